"""Sensory coding: foveal patches, batched OMP / MP, learnable dictionaries, binocular encoders."""

from aectorch.coding.dictionary import (
    DictionaryOutput,
    SparseDictionary,
    pooled_activity,
    reconstruction_error,
)
from aectorch.coding.encoder import BinocularEncoder, EncoderConfig, EncoderOutput
from aectorch.coding.patches import (
    COARSE, DEFAULT_SCALES, FINE, FULL, WIDE, WINDOW, FovealPatches, Scale, extract_patches, patch_permutation,
    pyramid_down, reduced_patches, scale_patches, window_patches,
)
from aectorch.coding.pursuit import gram_matrix, matching_pursuit, omp, use_backend
from aectorch.coding.sparse_code import SparseCode

__all__ = [
    "BinocularEncoder",
    "COARSE",
    "DEFAULT_SCALES",
    "DictionaryOutput",
    "EncoderConfig",
    "EncoderOutput",
    "FINE",
    "FovealPatches",
    "Scale",
    "SparseCode",
    "SparseDictionary",
    "WIDE",
    "WINDOW",
    "FULL",
    "extract_patches",
    "gram_matrix",
    "matching_pursuit",
    "omp",
    "patch_permutation",
    "pooled_activity",
    "pyramid_down",
    "reconstruction_error",
    "reduced_patches",
    "scale_patches",
    "use_backend",
    "window_patches",
]
