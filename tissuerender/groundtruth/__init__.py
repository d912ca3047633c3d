"""Ground truth for vision (issue 18; docs/ground-truth.md): per-frame passes that say exactly what each pixel
sees (``passes``: depth, normal, segmentation, material coordinates), the cameras that saw it and the
instance table (``cameras``), the laparoscope's lens and its remap (``lens``), and their files (``output``)."""
from tissuerender.groundtruth.cameras import (CONVENTIONS, camera_entry, cameras_document, intrinsics, labels,
                                              world_to_camera)
from tissuerender.groundtruth.lens import FisheyeLens, distort, fisheye_lens, undistort
from tissuerender.groundtruth.output import PASSES_FOLDER, pass_path, write_cameras, write_labels, write_passes
from tissuerender.groundtruth.passes import PASS_NAMES, ground_truth, rest_positions

__all__ = ["CONVENTIONS", "PASS_NAMES", "PASSES_FOLDER", "FisheyeLens", "camera_entry", "cameras_document", "distort",
           "fisheye_lens", "ground_truth", "intrinsics", "labels", "pass_path", "rest_positions", "undistort",
           "world_to_camera", "write_cameras", "write_labels", "write_passes"]
