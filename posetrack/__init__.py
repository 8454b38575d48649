"""posetrack: differentiable multiple-hypothesis 3D human pose tracking from RGB-D video."""

from ._camera import Intrinsics as Intrinsics
from ._camera import backproject as backproject
from ._camera import project as project

__all__ = ["Intrinsics", "backproject", "project"]
