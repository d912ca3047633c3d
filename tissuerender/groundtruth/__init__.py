"""Ground truth for vision (issue 18; docs/ground-truth.md): per-frame passes that say exactly what each pixel
sees (``passes``: depth, normal, segmentation, material coordinates), the cameras that saw it and the
instance table (``cameras``), the laparoscope's lens and its remap (``lens``), and their files (``output``); the
motion passes (flow, scene flow, tracks) from each frame's render geometry (``motion``, ``tracks``, ``sequence``)."""
from tissuerender.groundtruth.cameras import (CONVENTIONS, camera_entry, cameras_document, intrinsics, labels,
                                              scope_mask_id, world_to_camera)
from tissuerender.groundtruth.lens import FisheyeLens, distort, fisheye_lens, undistort
from tissuerender.groundtruth.motion import Geometry, flow_between, frame_geometry
from tissuerender.groundtruth.output import (PASSES_FOLDER, geometry_path, pass_path, read_geometry, write_cameras,
                                             write_geometry, write_labels, write_passes)
from tissuerender.groundtruth.passes import ground_truth, rest_positions
from tissuerender.groundtruth.passes import PASS_NAMES as ALL_PASS_NAMES
from tissuerender.groundtruth.scope import mark_scope_mask
from tissuerender.groundtruth.sequence import MOTION_PASSES, finish_sequence, flow_between_frames, frame_pass_files

# the passes one frame makes on its own (render_passes); the motion passes need the sequence's frames
PASS_NAMES = tuple(name for name in ALL_PASS_NAMES if name not in MOTION_PASSES)

__all__ = ["ALL_PASS_NAMES", "CONVENTIONS", "FisheyeLens", "Geometry", "MOTION_PASSES", "PASS_NAMES", "PASSES_FOLDER",
           "camera_entry", "cameras_document", "distort", "finish_sequence", "fisheye_lens", "flow_between",
           "flow_between_frames", "frame_geometry", "frame_pass_files", "geometry_path", "ground_truth", "intrinsics",
           "labels", "mark_scope_mask", "pass_path", "read_geometry", "rest_positions", "scope_mask_id", "undistort", "world_to_camera", "write_cameras",
           "write_geometry", "write_labels", "write_passes"]
