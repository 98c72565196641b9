"""Reading and validating the user's inputs (target, source, mask, optional depth map) and writing
outputs atomically.

Images come back as HxWx3 uint8 RGB with the EXIF orientation applied, masks as HxW bool (True =
hole). Every problem is a named exception of :mod:`geofill.errors` whose one-line message starts
with the file (or array) it is about.

- :mod:`~geofill.io.images`: image and mask files, their EXIF lens tags and carried metadata.
- :mod:`~geofill.io.arrays`: arrays at the API edge and the checks of one fill's inputs.
- :mod:`~geofill.io.output`: output checks made before any work (an output must not be an
  input), and the atomic, durable image write.
- :mod:`~geofill.io.depth_files`: user-supplied depth maps.
- :mod:`~geofill.io.reference_masks`: what must not be copied from each reference (its mask file,
  ``<stem>.mask.png`` beside it in a folder).
"""

from .arrays import MASK_THRESHOLD, as_rgb_uint8, as_source_mask, as_unit_float, validate_pair
from .depth_files import read_depth_file
from .images import (
    IMAGE_SUFFIXES,
    INPUT_FORMATS,
    ExifCamera,
    ImageMetadata,
    JpegTables,
    LoadedImage,
    read_image,
    read_mask,
)
from .output import (
    LOSSY_SUFFIXES,
    check_output_dir,
    check_output_path,
    file_id,
    file_ids,
    remove_partial_writes,
    replace_durably,
    write_image_atomic,
)
from .reference_masks import is_reference_mask, read_reference_mask, split_reference_masks

__all__ = [
    "IMAGE_SUFFIXES",
    "INPUT_FORMATS",
    "LOSSY_SUFFIXES",
    "MASK_THRESHOLD",
    "ExifCamera",
    "ImageMetadata",
    "JpegTables",
    "LoadedImage",
    "as_rgb_uint8",
    "as_source_mask",
    "as_unit_float",
    "check_output_dir",
    "check_output_path",
    "file_id",
    "file_ids",
    "is_reference_mask",
    "read_depth_file",
    "read_image",
    "read_mask",
    "read_reference_mask",
    "remove_partial_writes",
    "replace_durably",
    "split_reference_masks",
    "validate_pair",
    "write_image_atomic",
]
