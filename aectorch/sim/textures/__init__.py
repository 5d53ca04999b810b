"""Textures for the object plane: 1/f^alpha procedural noise and folders of photographs.

The paper puts one of 100 natural-image textures on the plane in front of the robot for each
fixation, and the AEC lineage holds out 40 more textures for testing. We cannot ship or download
those photographs, so `TextureBank.default` stands in 1/f^alpha random-phase textures from fixed
seeds: 100 for ``"train"`` and 40 different ones for ``"test"``. Any folder of PNG/JPEG photographs
can replace them with `TextureBank.from_folder`.

- `procedural`: the generated images (`pink_noise_images`, `dead_leaves_image`);
- `files`: image files read as grey textures (`IMAGE_EXTENSIONS`);
- `storage`: large texture tensors in a file mapped into memory (`empty_textures`);
- `bank`: `TextureBank`, the container environments draw from.
"""

from aectorch.sim.textures.bank import DEFAULT_SEEDS, DEFAULT_SIZES, PROCEDURAL_TEXTURES, TextureBank
from aectorch.sim.textures.files import IMAGE_EXTENSIONS
from aectorch.sim.textures.procedural import dead_leaves_image, pink_noise_images
from aectorch.sim.textures.storage import TEXTURE_RAM_BYTES, empty_textures, texture_ram_bytes

__all__ = ["TextureBank", "dead_leaves_image", "empty_textures", "pink_noise_images", "texture_ram_bytes",
           "DEFAULT_SEEDS", "PROCEDURAL_TEXTURES", "DEFAULT_SIZES", "IMAGE_EXTENSIONS", "TEXTURE_RAM_BYTES"]
