"""What a user sees in RViz after a localization: the hypotheses as a PoseArray and as
arrows with their scores, and the scan's local map placed at the estimate (the thesis's
own picture of a match) as an OccupancyGrid in the map frame."""
from __future__ import annotations

import math

import numpy as np
from geometry_msgs.msg import PoseArray
from nav_msgs.msg import OccupancyGrid
from std_msgs.msg import Header
from visualization_msgs.msg import Marker, MarkerArray

from ..core.local_grid import build_local_grid
from ..core.localizer import LocalizationResult
from ..core.scan import ScanPoints
from ..core.transform import Rigid2D
from .convert import pose_to_msg

CHOSEN = (0.1, 0.8, 0.2)     # green: the pose the server would publish
OTHER = (1.0, 0.55, 0.0)     # orange: the other hypotheses


def hypotheses_msg(result: LocalizationResult, header: Header) -> PoseArray:
    """The hypotheses, best first."""
    msg = PoseArray(header=header)
    msg.poses = [pose_to_msg(h.pose) for h in result.hypotheses]
    return msg


def markers_msg(result: LocalizationResult, header: Header) -> MarkerArray:
    """An arrow and a score label per hypothesis (the best green when it is a success),
    after a DELETEALL (in the header's frame, unstamped) so the previous localization's
    markers go."""
    out = MarkerArray()
    clear = Marker(action=Marker.DELETEALL)
    clear.header.frame_id = header.frame_id
    out.markers.append(clear)
    for i, h in enumerate(result.hypotheses):
        chosen = i == 0 and result.success
        r, g, b = CHOSEN if chosen else OTHER
        for kind, ns in ((Marker.ARROW, 'hypotheses'), (Marker.TEXT_VIEW_FACING, 'scores')):
            m = Marker(header=header, type=kind, action=Marker.ADD, ns=ns, id=i)
            m.pose = pose_to_msg(h.pose)
            m.color.r, m.color.g, m.color.b, m.color.a = r, g, b, 1.0
            if kind == Marker.ARROW:
                m.scale.x, m.scale.y, m.scale.z = 0.8, 0.12, 0.12
            else:
                m.pose.position.z = 0.5
                m.scale.z = 0.3
                m.text = (f'{i + 1}: {h.score:.3f}' + (f' on {h.map}' if h.map else '')
                          + (f' ({result.outcome.label})' if i == 0 else ''))
            out.markers.append(m)
    return out


def local_map_msg(points: ScanPoints, resolution: float, closing_kernel: int, map_T_laser: Rigid2D,
                  header: Header, max_range: float = math.inf) -> OccupancyGrid:
    """The scan's local map (rasterized, cropped, closed: core.local_grid) placed with the
    laser at `map_T_laser` in the header's frame; obstacle cells 100, the rest unknown."""
    local = build_local_grid(points, resolution, closing_kernel, max_range=max_range)
    map_T_grid = map_T_laser * local.grid_T_laser().inverse()
    msg = OccupancyGrid(header=header)
    msg.info.resolution = float(resolution)
    msg.info.width, msg.info.height = local.width, local.height
    msg.info.origin = pose_to_msg(map_T_grid)
    msg.data = np.where(np.flipud(local.image) > 0, 100, -1).astype(np.int8).ravel().tolist()
    return msg
