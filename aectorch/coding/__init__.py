"""Sensory coding: foveal patches, batched OMP / MP, learnable dictionaries, binocular encoders, and
the read-outs of a learned code (binocularity, disparity tuning, orientation)."""

from aectorch.coding.dictionary import (
    DictionaryOutput,
    SparseDictionary,
    pooled_activity,
    reconstruction_error,
)
from aectorch.coding.encoder import BinocularEncoder, EncoderConfig, EncoderOutput
from aectorch.coding.patches import (
    COARSE, DEFAULT_SCALES, FINE, FULL, WIDE, WINDOW, FovealPatches, Scale, extract_patches, fovea_weights, patch_energy,
    patch_permutation,
    pyramid_down, reduced_patches, scale_patches, window_patches,
)
from aectorch.coding.batch_omp import gram_matrix, matching_pursuit, omp, use_backend
from aectorch.coding.readouts import (
    binocularity_histogram, binocularity_index, code_summary, disparity_histogram, disparity_tuning,
    orientation_histogram, orientation_preference, preferred_disparity,
)
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
    "binocularity_histogram",
    "binocularity_index",
    "code_summary",
    "disparity_histogram",
    "disparity_tuning",
    "extract_patches",
    "gram_matrix",
    "matching_pursuit",
    "omp",
    "orientation_histogram",
    "orientation_preference",
    "fovea_weights",
    "patch_energy",
    "patch_permutation",
    "pooled_activity",
    "preferred_disparity",
    "pyramid_down",
    "reconstruction_error",
    "reduced_patches",
    "scale_patches",
    "use_backend",
    "window_patches",
]
