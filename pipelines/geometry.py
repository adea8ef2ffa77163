"""SE(3) and pinhole-camera geometry: re-exported from the bottom layer `litevloc.base.geometry`
(moved there so `hw` and `config` use it without importing the algorithm package)."""

from __future__ import annotations

from litevloc.base.geometry import (
    F64 as F64,
)
from litevloc.base.geometry import (
    GeometryError as GeometryError,
)
from litevloc.base.geometry import (
    PinholeIntrinsics as PinholeIntrinsics,
)
from litevloc.base.geometry import (
    backproject_depth as backproject_depth,
)
from litevloc.base.geometry import (
    backproject_pixels as backproject_pixels,
)
from litevloc.base.geometry import (
    check_rigid as check_rigid,
)
from litevloc.base.geometry import (
    compose as compose,
)
from litevloc.base.geometry import (
    interpolate_pose as interpolate_pose,
)
from litevloc.base.geometry import (
    interpolate_pose_at as interpolate_pose_at,
)
from litevloc.base.geometry import (
    invert as invert,
)
from litevloc.base.geometry import (
    is_rigid as is_rigid,
)
from litevloc.base.geometry import (
    make_T as make_T,
)
from litevloc.base.geometry import (
    matrix_to_quat_xyzw as matrix_to_quat_xyzw,
)
from litevloc.base.geometry import (
    project as project,
)
from litevloc.base.geometry import (
    project_to_so3 as project_to_so3,
)
from litevloc.base.geometry import (
    quat_xyzw_to_matrix as quat_xyzw_to_matrix,
)
from litevloc.base.geometry import (
    register_depth as register_depth,
)
from litevloc.base.geometry import (
    relative_pose_error as relative_pose_error,
)
from litevloc.base.geometry import (
    rotation_angle as rotation_angle,
)
from litevloc.base.geometry import (
    slerp_xyzw as slerp_xyzw,
)
from litevloc.base.geometry import (
    so3_exp as so3_exp,
)
from litevloc.base.geometry import (
    so3_log as so3_log,
)
from litevloc.base.geometry import (
    transform_points as transform_points,
)
