"""Localization health and the decision to relocalize, without ROS: the server feeds it
what it sees (a pose from the localizer, the fit of each scan at the pose it believes,
the end of each relocalization) and asks it the state and whether to relocalize now.

The fit is the one the matchers rank poses by: the field score (about the share of the
scan the map explains) x (1 - the share of beams through mapped walls). Defaults chosen
on the benchmark's scans (`python -m global_loc.bench --suites relocalization`, its fit
table, benchmarks/results/relocalization): at true poses the fit's 1st percentile is 0.83
on simulated scans and 0.51 on the real held-out logs; at random poses its 95th
percentile is 0.21 on the real logs and 0.43 on the simulated maps, which include a
symmetric room and twin aisles where random places do look alike. So `lost` below 0.4,
and only
when it stays there for `lost_after_s` (one low scan at a true pose is a 1-in-100 event;
three seconds of them is not noise).
"""
from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Optional


class Health(enum.Enum):
    UNKNOWN = 'unknown'             # no pose from the localizer yet
    LOCALIZED = 'localized'
    DEGRADED = 'degraded'           # the fit is low, not (yet) long enough to call it lost
    LOST = 'lost'
    RELOCALIZING = 'relocalizing'   # a global localization runs, or its pose waits for the localizer
    AMBIGUOUS = 'ambiguous'         # the last relocalization found more than one place


@dataclass(frozen=True)
class SupervisorConfig:
    degraded_fit: float = 0.5       # below: degraded
    lost_fit: float = 0.4           # below for lost_after_s: lost
    lost_after_s: float = 3.0
    auto_relocalize: bool = False   # relocalize on its own (it publishes poses: opt in)
    start_delay_s: float = 2.0      # with no pose ever received, wait this long after start before relocalizing
    min_interval_s: float = 10.0    # between two relocalizations
    max_attempts: int = 3           # in a row without recovering; then stay lost and say so
    settle_s: float = 10.0          # after publishing, how long the localizer has to take the pose


class Supervisor:
    def __init__(self, config: SupervisorConfig, now: float):
        self.config = config
        self.started = now
        self.health = Health.UNKNOWN
        self.fit: Optional[float] = None
        self.pose_received = False
        self.low_since: Optional[float] = None
        self.attempts = 0
        self.last_attempt: Optional[float] = None
        self.running = False
        self.published_at: Optional[float] = None     # a relocalized pose waits for the localizer
        self.last_pose_at: Optional[float] = None     # when the localizer last reported a pose
        self.note = ''

    def on_pose(self, now: float) -> None:
        """The localizer reported a pose (e.g. /amcl_pose)."""
        self.pose_received = True
        self.last_pose_at = now

    def _expire_settling(self, now: float) -> None:
        """A published pose the localizer did not take within settle_s (it was not up yet,
        or missed the one message): back to what the state was, so the guards may retry.
        /initialpose is volatile, as AMCL subscribes it: a late subscriber never receives
        an old pose, so retrying is the only way it gets one."""
        c = self.config
        if self.published_at is None or self.running or now - self.published_at < c.settle_s:
            return
        if self.last_pose_at is None or self.last_pose_at < self.published_at:
            self.published_at = None
            self.health = Health.LOST if self.pose_received else Health.UNKNOWN
            self.note = f'the localizer took no pose within {c.settle_s:g} s of the one published; will retry'

    def on_fit(self, now: float, fit: float) -> Health:
        """The fit of a scan at the pose the localizer believes."""
        c = self.config
        self.fit = fit
        if fit >= c.lost_fit:
            self.low_since = None
        elif self.low_since is None:
            self.low_since = now
        if fit >= c.degraded_fit:
            if self.attempts or self.published_at is not None:
                self.note = 'recovered'
            self.attempts, self.published_at = 0, None
        if self.running:
            self.health = Health.RELOCALIZING
        elif self.published_at is not None and now - self.published_at < c.settle_s:
            self.health = Health.RELOCALIZING      # wait for the localizer to take the pose
        elif fit >= c.degraded_fit:
            self.health = Health.LOCALIZED
        elif self.low_since is not None and now - self.low_since >= c.lost_after_s:
            self.health = Health.LOST
        elif self.health != Health.AMBIGUOUS:
            self.health = Health.DEGRADED
        return self.health

    def should_relocalize(self, now: float, scan_arrived: bool = True) -> Optional[str]:
        """Why a relocalization should start now, or None. Never before a scan has arrived:
        an attempt without one could only end 'no scan' and would use up max_attempts
        while the laser is still starting."""
        c = self.config
        self._expire_settling(now)
        if not c.auto_relocalize or self.running or not scan_arrived:
            return None
        if self.published_at is not None and now - self.published_at < c.settle_s:
            return None
        if self.last_attempt is not None and now - self.last_attempt < c.min_interval_s:
            return None
        if self.attempts >= c.max_attempts:
            self.note = f'gave up after {self.attempts} relocalization(s); a pose from outside resets it'
            return None
        if not self.pose_received:
            return 'no pose from the localizer yet' if now - self.started >= c.start_delay_s else None
        if self.health in (Health.LOST, Health.AMBIGUOUS):
            return f'lost: fit {self.fit:.2f} below {c.lost_fit} for {c.lost_after_s:g} s'
        return None

    def started_relocalization(self, now: float) -> None:
        self.running = True
        self.attempts += 1
        self.last_attempt = now
        self.health = Health.RELOCALIZING

    def finished_relocalization(self, now: float, published: bool, ambiguous: bool, counted: bool = True) -> None:
        """A relocalization ended; `published`: its pose went out (confident). Not `counted`:
        it never reached a scan (none arrived, the server stopped): not an attempt at all.
        Whether the localizer took the pose is told by its next pose (on_pose), not assumed."""
        self.running = False
        if not counted:
            self.attempts -= 1
            self.last_attempt = None
            self.health = Health.LOST if self.pose_received else Health.UNKNOWN
        elif published:
            self.published_at = now
            self.health = Health.RELOCALIZING
        else:
            self.health = Health.AMBIGUOUS if ambiguous else Health.LOST
