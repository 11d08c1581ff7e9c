"""Start-up from the last pose: the last confident answer kept in a file (its map, the map
set it was unique in, its fit, covariance, the odometry at that moment and a stamp), and
its confirmation from one scan at start-up.

A confident answer says more than "the scan fits here": no other place of any map of the
set fits it within the lead the verdict needs. So a robot that was not moved since - it
sees what it saw, at the stored pose - is confirmed by the scan's fit there alone: the
pose refined within about a cell (motion.pose_fitter, the fit tracking and the health
watch use) must explain the scan as well as the stored answer did, within the lead a
confident answer needs at that fit, and lie within half the distance (and angle) that
makes two poses distinct hypotheses (bnb's distinct_m, distinct_angle): the stored
answer's own hypothesis. A place elsewhere that the scan could not tell apart
from the stored one would have been a rival of the stored answer, which then would not
have been confident. That costs a refinement, not a search. When odometry runs on across
the restart (the robot's base kept running), the stored pose is first moved by the
odometry since. Anything else - the scan fits worse (the robot was moved or carried
away, the world changed), the file is stale, from another map or from a set that lacked
a map now served - is not confirmed, and the caller searches in full. Nothing here
publishes anything: the caller does, as with any answer.
"""
from __future__ import annotations

import json
import math
import os
import tempfile
import time
from dataclasses import dataclass
from typing import Optional

import numpy as np

from .files import UnreadableFile, brief, read_small_text
from .localizer import Hypothesis, LocalizationResult
from .motion import pose_fitter
from .outcome import Outcome
from .scan import ScanPoints
from .transform import Rigid2D, format_pose

FORMAT = 'global_loc stored pose 1'


class StoredPoseError(ValueError):
    """A stored-pose file that cannot be read or used: missing, malformed, not finite."""


@dataclass(frozen=True)
class StoredPose:
    map: str                        # the map it is on
    maps: tuple                     # the map set it was confident in (every map it was unique among)
    pose: Rigid2D                   # robot base in the map frame
    fit: float                      # motion.pose_fitter's fit there (the answer's score)
    confidence: float               # the answer's
    covariance: tuple               # 3 x 3, row-major (x, y, yaw)
    stamp: float                    # when it was stored, s since the epoch
    odometry: Optional[Rigid2D] = None   # the odometry pose at the answer's scan, if known

    def as_dict(self) -> dict:
        return {'format': FORMAT, 'map': self.map, 'maps': list(self.maps), 'pose': list(self.pose.as_tuple()),
                'fit': self.fit, 'confidence': self.confidence, 'covariance': list(self.covariance),
                'stamp': self.stamp,
                'odometry': list(self.odometry.as_tuple()) if self.odometry is not None else None}

    @staticmethod
    def from_dict(d: dict, source: str = 'the stored pose') -> 'StoredPose':
        try:
            if d.get('format') != FORMAT:
                raise ValueError(f'format is {d.get("format")!r}, not {FORMAT!r}')
            odometry = d.get('odometry')
            stored = StoredPose(str(d['map']), tuple(map(str, d['maps'])), Rigid2D(*map(float, d['pose'])),
                                float(d['fit']), float(d['confidence']), tuple(map(float, d['covariance'])),
                                float(d['stamp']),
                                Rigid2D(*map(float, odometry)) if odometry is not None else None)
        except (KeyError, TypeError, ValueError, AttributeError) as e:
            raise StoredPoseError(f'{source} is malformed: {e}') from None
        numbers = [*stored.pose.as_tuple(), stored.fit, stored.confidence, *stored.covariance, stored.stamp,
                   *(stored.odometry.as_tuple() if stored.odometry is not None else ())]
        if len(stored.covariance) != 9 or not all(map(math.isfinite, numbers)) or not stored.map:
            raise StoredPoseError(f'{source} is malformed: a pose, fit, covariance (9 numbers) and stamp, all '
                                  f'finite, and a map name are needed')
        return stored


@dataclass(frozen=True)
class SinceStored:
    """What the start-up knows of the time since the pose was stored: how long ago that was
    (`age_s`, from the file's stamp), and the odometry at the scan now (`odometry`; None:
    not known), which the stored odometry is compared with."""
    age_s: float
    odometry: Optional[Rigid2D] = None


def stored_from_result(result: LocalizationResult, maps, stamp: float,
                       odometry: Optional[Rigid2D] = None) -> StoredPose:
    """What to keep of a confident answer (`maps`: the set it was searched in)."""
    if not result.success or result.pose is None:
        raise StoredPoseError('only a confident answer is stored')
    covariance = tuple(float(v) for v in np.asarray(result.covariance, float).ravel())
    return StoredPose(result.map or next(iter(maps)), tuple(maps), result.pose, float(result.score),
                      float(result.confidence), covariance, float(stamp), odometry)


def save_stored_pose(path: str, stored: StoredPose) -> None:
    """Write the file atomically (a temporary file in the same folder, then renamed over it):
    a crash mid-write leaves the previous pose, never half a file."""
    folder = os.path.dirname(os.path.abspath(path))
    os.makedirs(folder, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix='.stored_pose.', dir=folder)
    try:
        with os.fdopen(fd, 'w', encoding='utf-8') as f:
            json.dump(stored.as_dict(), f)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def load_stored_pose(path: str) -> StoredPose:
    """The stored pose in `path`; StoredPoseError saying why for any file that is not one:
    missing, not a regular file (a FIFO would block the request), too big, not JSON (a file
    of nested brackets too) or malformed - the caller then searches in full."""
    if not os.path.lexists(path):
        raise StoredPoseError(f'no stored pose in {path} (none saved yet)')
    try:
        d = json.loads(read_small_text(path))
    except UnreadableFile as e:
        raise StoredPoseError(f'the stored pose {path} cannot be read: it {e}') from None
    except ValueError as e:
        raise StoredPoseError(f'the stored pose {path} cannot be read: not JSON: {brief(str(e), 200)}') from None
    except RecursionError:
        raise StoredPoseError(f'the stored pose {path} cannot be read: not JSON: nested too deep') from None
    if not isinstance(d, dict):
        raise StoredPoseError(f'the stored pose {path} is malformed: not an object')
    return StoredPose.from_dict(d, f'the stored pose {path}')


def confirm_stored_pose(map_set, points: ScanPoints, stored: StoredPose, base_T_laser: Rigid2D,
                        since: SinceStored, max_age_s: float = 0.0) -> tuple[Optional[LocalizationResult], str]:
    """(the confirmed answer, '') or (None, why it is not confirmed). `map_set`: the maps
    served now (core.map_set.MapSet); `since`: the pose's age and the odometry now;
    `max_age_s`: older is stale (0: any age)."""
    t0 = time.perf_counter()
    age_s, odometry_now = since.age_s, since.odometry
    if not math.isfinite(age_s) or age_s < 0:
        # stamped in the future (the clock went back, or the file came from another machine):
        # an age that cannot be known is stale, whatever the limit
        when = f'stamped {-age_s:.0f} s in the future (the clock went back?)' if age_s < 0 else 'of no known age'
        return None, f'the stored pose is stale: {when}'
    if max_age_s > 0 and age_s > max_age_s:
        return None, f'the stored pose is stale: stored {age_s:.0f} s ago (stored_pose_max_age_s {max_age_s:g})'
    if stored.map not in map_set.localizers:
        return None, f'the stored pose is on map {stored.map}, which is not served (maps: {", ".join(map_set.names)})'
    new = [n for n in map_set.names if n not in stored.maps]
    if new:
        return None, (f'the stored pose was confident among maps {", ".join(stored.maps)}; map {", ".join(new)} '
                      f'was not searched then')
    tracker = map_set.tracker(on=stored.map)
    fit_at = pose_fitter(tracker, points, base_T_laser)
    starts = [('stored', stored.pose)]
    if stored.odometry is not None and odometry_now is not None:
        starts.insert(0, ('moved by odometry', stored.pose * (stored.odometry.inverse() * odometry_now)))
    need = stored.fit * (1.0 - tracker.lead_needed(stored.fit))
    best_fit = -math.inf
    for how, start in starts:
        fit, refined = fit_at(start)
        moved_m, turned = refined.distance_to(start)
        if moved_m > tracker.distinct_m / 2 or turned > tracker.distinct_angle / 2:
            continue        # the refinement left the hypothesis the stored answer was judged on
        best_fit = max(best_fit, fit)
        if math.isfinite(fit) and fit >= need:
            hyp = Hypothesis(refined, fit, stored.map)
            return LocalizationResult(
                Outcome.LOCALIZED, f'the stored pose confirmed ({how}; fit {fit:.3f}, stored '
                                   f'{stored.fit:.3f}, at least {need:.3f} needed; stored {age_s:.0f} s ago on map '
                                   f'{stored.map})',
                tracker.name, pose=refined, score=fit, confidence=stored.confidence,
                covariance=np.asarray(stored.covariance, float).reshape(3, 3), hypotheses=[hyp],
                map=stored.map, time_s=time.perf_counter() - t0), ''
    return None, (f'the scan does not confirm the stored pose {format_pose(stored.pose)} on map {stored.map}: fit '
                  f'{best_fit:.3f} there, at least {need:.3f} needed (stored {stored.fit:.3f})')
