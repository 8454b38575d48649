"""The application layer: the ``posetrack`` command line, the demo, result files, pictures.

Everything here is built on the public API of the core (``posetrack``), ``posetrack.io`` and
``posetrack.synth``; the core never imports this package (it takes callbacks instead of drawing
progress bars or pictures).
"""

from ._cli import main as main
from ._demo import run_demo as run_demo
from ._export import BVH_KEYPOINTS as BVH_KEYPOINTS
from ._export import SavedResults as SavedResults
from ._export import bvh_from_result as bvh_from_result
from ._export import check_output_dir as check_output_dir
from ._export import output_frame as output_frame
from ._export import save_results as save_results
from ._export import status_counts as status_counts
from ._machine import machine_info as machine_info
from ._machine import machine_summary as machine_summary
from ._overlay import write_overlay as write_overlay
from ._panel import PANELS as PANELS
from ._panel import SkeletonPanel as SkeletonPanel
from ._panel import render_panel as render_panel
from ._progress import Progress as Progress
from ._progress import ProgressBar as ProgressBar
from ._viz import CYAN as CYAN
from ._viz import GREEN as GREEN
from ._viz import GREY as GREY
from ._viz import RED as RED
from ._viz import YELLOW as YELLOW
from ._viz import colorize_depth as colorize_depth
from ._viz import contact_sheet as contact_sheet
from ._viz import crop_box as crop_box
from ._viz import draw_skeleton as draw_skeleton
from ._viz import line_plot as line_plot
from ._viz import put_label as put_label
from ._viz import write_gif as write_gif
from ._viz import write_png as write_png

__all__ = [
    # command line and demo
    "main",
    "run_demo",
    # result files
    "BVH_KEYPOINTS",
    "SavedResults",
    "bvh_from_result",
    "check_output_dir",
    "output_frame",
    "save_results",
    "status_counts",
    # pictures (RGB uint8 images, colours as RGB tuples)
    "CYAN",
    "GREEN",
    "GREY",
    "PANELS",
    "RED",
    "YELLOW",
    "colorize_depth",
    "contact_sheet",
    "crop_box",
    "draw_skeleton",
    "line_plot",
    "put_label",
    "render_panel",
    "SkeletonPanel",
    "write_gif",
    "write_overlay",
    "write_png",
    # progress and machine facts
    "Progress",
    "ProgressBar",
    "machine_info",
    "machine_summary",
]
