"""One localization, whoever asked, in one direction: admit (active? busy?) -> validate
(a core Request, defaults resolved once) -> localize (the newest map, the view of every
sensor's first message after the request - ros/sensors.py - converted once; motion when
asked) -> publish (only a pose the server can vouch for, in the map that is still
current). Every end is an outcome; nothing here raises to the executor.

`RequestPath` gets its collaborators passed in (`Collaborators`); it reads no node's fields.
"""
from __future__ import annotations

import dataclasses
import math
import threading
import time
import traceback
from dataclasses import dataclass
from typing import Callable, Optional

from global_loc_interfaces.action import Localize

from ..core.limits import BudgetError
from ..core.map_set import MapSet, MapSetError, MapSetPrior, tagged
from ..core.map_slot import MapSlot
from ..core.matchers import MethodError
from ..core.mount import LaserMount
from ..core.outcome import CanceledError, Outcome, Stage
from ..core.pose_history import PoseHistory
from ..core.request import Asked, Request, RequestError, make_request
from ..core.scan import ScanError, scan_to_points
from ..core.transform import Rigid2D, format_pose
from ..core.view import ViewError
from .convert import ended_result, result_to_msg, scan_from_msg, stamp_seconds
from .memory import release_free_memory
from .motion import MotionStart, resolve_by_motion
from .sensors import SensorInputs, make_view, silent

CLOCKS_APART_S = 3600.0     # a scan stamped this far from the node's clock: use_sim_time set wrong?


def seconds(value: float) -> str:
    """A duration for a log line: 1.0, 12.5, 1e+308 (not 309 digits)."""
    return f'{value:.1f}' if value < 1e6 else f'{value:.3g}'


@dataclass
class Collaborators:
    config: Callable[[], object]                 # -> the current ros.parameters.ServerConfig
    maps: MapSlot                                # of Localizer
    sensors: SensorInputs                        # every sensor's newest message
    mount: Callable                              # (SensorSpec, frame) -> its Mount3D on the base (NoMounting)
    laser_mount: Callable[[str], LaserMount]     # the primary laser's frame -> its LaserMount (MountError)
    odometry: PoseHistory                        # moves each reading to the view's stamp
    motion: Callable[[], object]                 # -> the ros.motion.MotionContext while configured
    publish_pose: Callable[[object], None]       # PoseWithCovarianceStamped -> initialpose_topic
    publish_map: Callable[[str], None]           # the map a confident answer is on -> ~/current_map (latched)
    show: Callable                               # (result, scan, base_T_laser, stamp, map) -> RViz topics
    clock_now: Callable[[], float]               # the node's clock (sim time with use_sim_time), s
    logger: object
    pose_file: Callable[[], object] = lambda: None   # -> the ros.pose_file.PoseFile, or None (off)


@dataclass(frozen=True)
class Asker:
    """Who asked, as the path reaches them while it works: whether they cancelled, and the
    action's feedback (progress, stage, best score, hypotheses); a service has neither."""
    cancelled: Callable[[], bool] = lambda: False
    feedback: Callable[..., None] = lambda *a: None


@dataclass(frozen=True)
class Job:
    """One admitted request as the path carries it: what was asked, the server's configuration
    as it was at admission (read once: the request sees one consistent snapshot), who
    asked, and when it started (time.monotonic)."""
    request: Request
    config: object              # ros.parameters.ServerConfig
    asker: Asker
    start: float


class RequestPath:
    def __init__(self, c: Collaborators):
        self.c = c
        self.active = False
        self.stopping = threading.Event()       # set: running work ends (deactivate, cleanup, shutdown)
        self.busy = threading.Lock()
        # One per configuration served: a request admitted under an earlier one ends canceled
        # at its next step even when the server is active again (deactivate -> activate).
        self.epoch = 0

    def stop(self) -> None:
        """Stop accepting work; what runs ends canceled at its next step, whatever follows."""
        self.active = False
        self.epoch += 1
        self.stopping.set()

    # ---- admit and validate ------------------------------------------------------------
    def serve(self, asked: Asked, asker: Asker = Asker()) -> Localize.Result:
        """One request, as asked; never raises."""
        if not self.active:
            return self.end_early(Outcome.NOT_ACTIVE, self.inactive_reason)
        if not self.busy.acquire(blocking=False):
            return self.end_early(Outcome.BUSY, 'busy: another localization is running (one at a time); retry when '
                                             'it ends', throttle=True)
        epoch = self.epoch

        def gone() -> bool:       # the configuration this request was admitted under has ended
            return self.stopping.is_set() or self.epoch != epoch
        try:
            config = self.c.config()       # one snapshot for the request: a parameter set meanwhile applies to the next
            request = make_request(asked, config.request_defaults())
            return self.run(Job(request, config, Asker(lambda: asker.cancelled() or gone(), asker.feedback),
                                time.monotonic()))
        except RequestError as e:
            return self.end_early(Outcome.BAD_GOAL, f'bad request: {e}')
        except CanceledError:
            reason = 'canceled' if not gone() else 'canceled: the server is stopping'
            self.c.logger.info(reason)
            return ended_result(Outcome.CANCELED, reason)
        except Exception as e:   # an internal error must end this request, not the node
            self.c.logger.error(f'internal error: {e}\n{traceback.format_exc()}')
            return ended_result(Outcome.INTERNAL_ERROR, f'internal error: {type(e).__name__}: {e}')
        finally:
            self.busy.release()
            release_free_memory()

    inactive_reason = 'not active: the server is not in the active lifecycle state'

    def end_early(self, outcome: Outcome, message: str, throttle: bool = False) -> Localize.Result:
        """End the request before (or instead of) a localization result: refused at once
        (inactive, busy, bad), or after waiting (no scan, no map, an unusable scan)."""
        # two call sites: rclpy refuses one call site logged with and without a throttle
        if throttle:
            self.c.logger.warn(f'refused: {message}', throttle_duration_sec=5.0)
        else:
            self.c.logger.warn(f'refused: {message}')
        return ended_result(outcome, message)

    # ---- localize ---------------------------------------------------------------------
    def run(self, job: 'Job') -> Localize.Result:
        request, asker, cancelled = job.request, job.asker, job.asker.cancelled
        maps = self.c.maps.wait_current(request.scan_timeout_s, cancelled)   # a newer map may be building
        if maps.built is None or not self.c.maps.is_current(maps.generation):
            return self.end_early(Outcome.NO_MAP, maps.error or 'a newer map is still being prepared; retry')
        localizer = maps.built.reconfigured(job.config.localizer)     # a MapSet (one map or several)
        try:
            localizer.matcher(request.method)       # prepared with the map, or refused now: never built here
            localizer.searched(request.maps)
        except (MethodError, MapSetError) as e:
            return self.end_early(Outcome.BAD_GOAL, f'bad request: {e}')
        try:
            seen = self.wait_for_view(job)
            if seen is None:
                return self.end_early(Outcome.NO_SCAN, f'no {self.wanted()} within {seconds(request.scan_timeout_s)} s')
            view, messages = seen
            self.log_view(view, messages)
            result, not_confirmed = self.from_stored_pose(job, localizer, view, messages)
            if result is None:
                result = localizer.localize_points(view.points, request.method, request.angle_step_deg,
                                                   self.progress(asker), base_T_laser=view.base_T_laser,
                                                   prior=MapSetPrior(request.maps, request.region))
            if not_confirmed:
                result = dataclasses.replace(result, message=f'{result.message} (searched in full: {not_confirmed})')
        except ScanError as e:      # ViewError, MountError, NoMounting are ScanErrors
            return self.end_early(Outcome.UNUSABLE_SCAN, f'scan unusable: {e}')
        except BudgetError as e:    # the goal asks for more work than a goal may do
            return self.end_early(Outcome.BAD_GOAL, f'bad request: {e}')
        reference = max(messages.values(), key=lambda m: stamp_seconds(m.header.stamp))
        shown = (view.points, view.base_T_laser, reference)
        if result.outcome == Outcome.AMBIGUOUS and request.resolve_by_motion_s > 0:
            result, shown = self.resolve_by_motion(result, messages, job, localizer, shown)
        specs = self.c.sensors.specs
        if len(specs) > 1 or specs[0].kind != 'scan':     # one laser alone: its messages as they always were
            result = dataclasses.replace(result, message=f'{result.message} [{view.summary()}]')
        if cancelled():     # asked to end, or its configuration ended, after the search's last step
            raise CanceledError()
        return self.publish(job, result, shown, maps.generation, localizer)

    def from_stored_pose(self, job: 'Job', map_set: MapSet, view, messages: dict) -> tuple:
        """(the stored pose confirmed by the view, '') when the request asks for it and the file
        confirms; (None, why not) when it asks and it does not; (None, '') otherwise."""
        if not job.request.from_stored_pose:
            return None, ''
        pose_file = self.c.pose_file()
        if pose_file is None:
            return None, 'no stored_pose_file is set'
        stamp = max(stamp_seconds(m.header.stamp) for m in messages.values())
        result, why = pose_file.confirm(map_set, view.points, view.base_T_laser, stamp,
                                        job.config['stored_pose_max_age_s'])
        self.c.logger.info('the stored pose is confirmed' if result is not None else
                           f'the stored pose is not confirmed: {why}; searching in full')
        return result, why

    def resolve_by_motion(self, result, messages: dict, job: 'Job', localizer, shown: tuple) -> tuple:
        """Followed over the primary laser's scans (the watch's laser); (result, what to show)."""
        primary = next((s for s in self.c.sensors.specs if s.primary), None)
        if primary is None or primary.topic not in messages:
            note = (f'the primary laser {primary.topic} is not in the view' if primary is not None
                    else 'it needs a laser (scan_topics)')
            return dataclasses.replace(result, message=f'{result.message} (cannot resolve by motion: {note})'), shown
        msg = messages[primary.topic]
        on = {h.map for h in result.hypotheses}
        if len(on) > 1:
            note = f'cannot resolve by motion across maps {", ".join(sorted(on))}: name the map in the goal\'s maps'
            return dataclasses.replace(result, message=f'{result.message} ({note})'), shown
        on_map, localizer = result.map, localizer.localizers[result.map]
        try:
            mount = self.c.laser_mount(msg.header.frame_id)
        except ScanError as e:
            return dataclasses.replace(result, message=f'{result.message} (cannot resolve by motion: {e})'), shown
        result, last = resolve_by_motion(self.c.motion(), MotionStart(result, msg, mount.base_T_laser, localizer),
                                         job.request, job.config['rotate_speed'], job.asker.cancelled,
                                         job.asker.feedback)
        result = tagged(result, on_map)         # the follower's answer is on the map it followed on
        if last is msg:
            return result, shown
        return result, (scan_to_points(mount.upright(scan_from_msg(last))), mount.base_T_laser, last)

    def wanted(self) -> str:
        """What a request waits for: 'scan on /scan', 'message on /scan, /points'."""
        specs = self.c.sensors.specs
        what = 'scan' if all(s.kind == 'scan' for s in specs) else 'sensor message'
        return f'{what} on {", ".join(s.topic for s in specs)}'

    def wait_for_view(self, job: 'Job') -> Optional[tuple]:
        """(view, topic -> message) of the first messages after the request (make_view); None when
        none arrives within the scan timeout. While none is usable and a sensor has said nothing
        since the request (one that starts late), its messages are waited for, up to the timeout."""
        request, asker, sensors = job.request, job.asker, self.c.sensors
        self.c.logger.info(f'localizing ({request.origin}): method {request.method}, waiting up to '
                           f'{seconds(request.scan_timeout_s)} s for a {self.wanted()}')
        asker.feedback(0.0, Stage.WAITING_FOR_SCAN, 0.0)
        since, unusable, end = job.start, None, job.start + request.scan_timeout_s
        while True:
            newest = sensors.wait(since, end - since, job.config.view.merge_window_s, asker.cancelled)
            if newest is None and unusable is not None:
                raise unusable
            if newest is None:
                return None
            asker.feedback(0.05, Stage.PREPARING_SCAN, 0.0)   # local map or points, per method
            try:
                return make_view(sensors, newest, job.start, self.c.mount, self.c.odometry, job.config.view)
            except ViewError as e:
                waited = [s.topic for s in sensors.specs if silent(newest, s.topic, job.start)]
                if not waited or time.monotonic() >= end:
                    raise
                self.c.logger.info(f'no usable view yet ({e}); waiting for {", ".join(waited)}',
                                   throttle_duration_sec=5.0)
                since, unusable = time.monotonic(), e

    def log_view(self, view, messages: dict) -> None:
        if len(self.c.sensors.specs) == 1 and hasattr(next(iter(messages.values())), 'ranges'):
            self.c.logger.info(f'matching a scan of {len(next(iter(messages.values())).ranges)} beams')
        else:
            self.c.logger.info(f'matching a scan view: {view.summary()}')

    @staticmethod
    def progress(asker: Asker):
        """The matchers' progress callback: cancel between search steps; at most ~10
        feedback messages a second."""
        last = [0.0]

        def report(fraction, best):
            if asker.cancelled():
                raise CanceledError()
            if time.monotonic() - last[0] > 0.1 or fraction >= 1.0:
                last[0] = time.monotonic()
                asker.feedback(0.05 + 0.9 * fraction, Stage.MATCHING, best)
        return report

    # ---- publish ------------------------------------------------------------------------
    def publish(self, job: 'Job', result, shown: tuple, generation: int, map_set: MapSet) -> Localize.Result:
        """The action result; the pose on /initialpose when it is confident (or asked for
        anyway), its map is still the newest received and it is on the served map (the map
        /map serves: a pose on another floor would put AMCL on the wrong map). `shown`:
        (points, base_T_laser, message) the pose is of - the view's newest, or
        resolve-by-motion's last scan. A confident answer's map goes on the current-map topic."""
        request, config = job.request, job.config
        # the one parameter read again, not from the snapshot: map_server may have switched maps
        # during the search, and a pose for the map it served before must not reach AMCL now
        served = self.c.config()['served_map'] or map_set.served
        occupancy_map = map_set.localizers.get(result.map, map_set.localizers[served]).map
        points, base_T_laser, msg = shown
        out = result_to_msg(result, config['map_frame'], msg.header.stamp, time.monotonic() - job.start)
        out.scan_stamp = msg.header.stamp
        out.scan_age_s = self.scan_age(msg)
        self.c.show(result, points, base_T_laser, msg.header.stamp, occupancy_map)
        summary = result.message
        if result.pose is not None:
            summary += f': {format_pose(result.pose)}, score {result.score:.3f}, {result.time_s:.2f} s'
            wanted = request.publish and (result.success or request.publish_if_ambiguous)
            if wanted and not self.c.maps.is_current(generation):
                return self.end_early(Outcome.NO_MAP, f'not published: a newer map arrived while localizing in map '
                                                   f'{generation} (its pose would be in the old map); retry')
            if result.success:
                self.c.publish_map(result.map)
            if wanted and result.map != served:
                note = (f'not published on {config["initialpose_topic"]}: the answer is on map {result.map}, /map '
                        f'serves {served} (switch map_server to it - its load_map service - and set served_map; '
                        f'docs/SERVER.md)')
                out.message, summary = f'{out.message}; {note}', f'{summary}; {note}'
            elif wanted:
                self.c.publish_pose(out.pose)
                summary += f'; published on {config["initialpose_topic"]}'
                if result.success and self.c.pose_file() is not None:
                    self.store(result, request, stamp_seconds(msg.header.stamp), map_set)
        self.c.logger.info(summary)
        return out

    def store(self, result, request: Request, stamp: float, map_set: MapSet) -> None:
        """Keep a confident answer in the stored-pose file, unless it was confident only within
        a search prior: the file keeps no prior, and its confirmation at the next start-up
        stands on the answer having been unique in every map it lists."""
        if request.region.bounded:
            self.c.logger.info('the pose is not stored: it is confident within the search prior, not over the '
                               'whole map')
            return
        self.c.pose_file().save(result, stamp, map_set.searched(request.maps))

    def scan_age(self, msg) -> float:
        age = self.c.clock_now() - stamp_seconds(msg.header.stamp)
        if not math.isfinite(age) or abs(age) > CLOCKS_APART_S:
            self.c.logger.warn(f'the scan is stamped {age:.3g} s from this node\'s clock: is use_sim_time the same '
                               f'for the laser and this server? (poses are stamped with the scan\'s time)',
                               throttle_duration_sec=10.0)
        return age


def asked_by_goal(goal) -> Asked:
    """A Localize goal, as asked."""
    c = goal.search_center
    return Asked(origin='goal', method=goal.method, angle_step_deg=goal.angle_step_deg, timeout_s=goal.timeout_s,
                center=Rigid2D(c.x, c.y, c.theta), radius_m=goal.search_radius_m,
                yaw_tolerance_deg=goal.search_yaw_tolerance_deg, resolve_by_motion_s=goal.resolve_by_motion_s,
                rotate_in_place=goal.rotate_in_place, publish=goal.publish_initialpose,
                publish_if_ambiguous=goal.publish_if_ambiguous, maps=tuple(goal.maps))


def trigger_message(result: Localize.Result, pose: Optional[Rigid2D]) -> str:
    """~/trigger's one line: the result's message (it says the outcome), the pose when there is one."""
    text = result.message
    if pose is not None:
        text += f'; {format_pose(pose)}, confidence {result.confidence:.2f}'
    return text


def publish_feedback(goal_handle, progress, stage, best, hypotheses=0) -> None:
    """The action's feedback (the `feedback` callback a goal's path reports through)."""
    goal_handle.publish_feedback(Localize.Feedback(progress=float(progress), stage=stage, hypotheses=int(hypotheses),
                                                   best_score=float(best) if math.isfinite(best) else 0.0))
