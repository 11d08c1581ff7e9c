"""Several maps at once - the floors of a building, the sites of a fleet: which map am I on,
and where in it. Each map is searched by its own Localizer with the same verdict; the
answer across maps is judged by the same lead rule as the places within one map, so a
place that two maps share (the stairwell of identical floors, a lobby two sites copied)
is `ambiguous` with a hypothesis on each, never a guess.

A map's best hypothesis is the best place of that map (bnb's search is exhaustive; a
checked thesis matcher's rival search covers the rest of its map), so comparing the maps'
best places is enough: the best map's answer stays confident only when every other map's
best place lies behind it by the lead a confident answer needs at its fit. Proving that no
place of a map comes that close is far cheaper than finding its best: short probes of every
map find the best leaf some map reaches, and each map's search then takes it as bnb's
incumbent (only the band below it is searched), going on from where the map's probe
stopped (bnb keeps a probe's search: its work is not done again). A map whose search
stopped early could hide a better place: a confident answer then becomes `search
incomplete`, saying which map.
"""
from __future__ import annotations

import dataclasses
import math
import os
import time
from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
from scipy.spatial import cKDTree

from .files import UnreadableFile, brief, read_yaml_file
from .localizer import LocalizationResult, Localizer, SearchLimits
from .matchers import TRACKER_METHOD, resolve_method
from .matchers.base import ProgressFn
from .outcome import Outcome
from .scan import Scan, scan_to_points
from .search_region import SearchRegion
from .transform import Rigid2D

PROBE_NODES = (300, 2_000)    # the probe rounds' node budgets (bnb expansions) on each map not yet done


class MapSetError(ValueError):
    """A map set that cannot be served as asked: no maps, two maps of one name, an unknown name."""


@dataclass(frozen=True)
class MapSetPrior:
    """Where a map set's search looks: on `maps` (by name; empty: every map of the set) and,
    on each of them, within `region` (of the robot base; None: anywhere)."""
    maps: Sequence[str] = ()
    region: Optional[SearchRegion] = None


def map_name(yaml_path: str) -> str:
    """A map's name by default: its YAML's file name without `.yaml` (office.yaml -> office)."""
    base = os.path.basename(str(yaml_path))
    return base[:-5] if base.endswith('.yaml') else base


def named_paths(entries, expand: bool = True) -> dict[str, str]:
    """Map YAMLs by name from PATH or NAME=PATH entries (the CLI's --map, the server's `maps`):
    an entry that is an existing file, or whose part before '=' holds a '/', is a path named
    by map_name. A map-set file - a YAML whose `maps` lists such entries (map YAMLs, paths
    relative to it) - stands for its entries (`expand`). MapSetError for two maps of one name
    or a bad map-set file."""
    out = {}
    for entry in map(str, entries):
        name, sep, path = entry.partition('=')
        if not sep or os.path.exists(entry) or not name or '/' in name:
            name, path = map_name(entry), entry
        listed = map_set_file_entries(path) if expand else None
        for one, its_path in (named_paths(listed, expand=False) if listed is not None else {name: path}).items():
            if one in out:
                raise MapSetError(f'two maps named {one}: name them apart (NAME=PATH)')
            out[one] = its_path
    return out


def _map_set_doc(path: str) -> Optional[dict]:
    """The document of a map-set file (a YAML mapping with `maps`), None for any other file:
    loading that as a map says what is wrong with it (the same reader refuses aliases, size)."""
    if not (path.endswith(('.yaml', '.yml')) and os.path.isfile(path)):
        return None
    try:
        doc = read_yaml_file(path)
    except UnreadableFile:
        return None
    return doc if isinstance(doc, dict) and 'maps' in doc else None


def map_set_file_entries(path: str) -> Optional[list[str]]:
    """The entries a map-set file lists (`maps:` PATH or NAME=PATH, or NAME: PATH), paths made
    relative to the file's folder; None for any other file (a map YAML has no `maps`).
    MapSetError for an entry that is not a map: a name holding '=' or '/', the file itself,
    another map-set file (sets do not nest)."""
    doc = _map_set_doc(path)
    if doc is None:
        return None
    listed = doc['maps']
    if not isinstance(listed, list) or not listed:
        raise MapSetError(f'map-set file {path}: `maps` must be a non-empty list of PATH, NAME=PATH or NAME: PATH')
    folder = os.path.dirname(os.path.abspath(path))
    return [_map_set_entry(item, path, folder) for item in listed]


def _map_set_entry(item, path: str, folder: str) -> str:
    """One entry of map-set file `path` as PATH or NAME=PATH, its path resolved against `folder`."""
    if isinstance(item, dict) and len(item) == 1:
        (name, target), = item.items()
        name = str(name)
        if '=' in name or '/' in name or not name:
            raise MapSetError(f'map-set file {path}: the map name {brief(name)} cannot be empty or hold "=" or "/"')
    elif isinstance(item, str) and item:
        name, sep, target = item.partition('=')
        if not sep or '/' in name:
            name, target = '', item
    else:
        name, target = '', None
    if not isinstance(target, str) or not target:
        raise MapSetError(f'map-set file {path}: an entry of `maps` must be PATH, NAME=PATH or NAME: PATH, '
                          f'got {brief(item)}')
    target = target if os.path.isabs(target) else os.path.join(folder, target)
    if os.path.exists(target) and os.path.samefile(target, path):
        raise MapSetError(f'map-set file {path}: the entry {brief(item)} is this file itself, not a map')
    if _map_set_doc(target) is not None:
        raise MapSetError(f'map-set file {path}: the entry {brief(item)} is another map-set file '
                          f'(sets do not nest: list its maps here)')
    return f'{name}={target}' if name else target


class MapSet:
    """Localizers by map name, in the order given; `localize` searches the ones asked (all by
    default) and answers on one of them, or ambiguous between them. `served`: the map the
    robot's map server serves (the first by default) - the one the watch checks a pose in."""

    def __init__(self, localizers: dict[str, Localizer], served: Optional[str] = None):
        if not localizers:
            raise MapSetError('a map set needs at least one map')
        self.localizers = dict(localizers)
        self._walls = {}      # map name -> its occupied cells' KD-tree, built when first needed (common_fits)
        self.served = served or next(iter(self.localizers))
        if self.served not in self.localizers:
            raise MapSetError(f'the served map {self.served} is not in the set (maps: {", ".join(self.names)})')

    @property
    def names(self) -> list[str]:
        return list(self.localizers)

    def reconfigured(self, config) -> 'MapSet':
        """Every map with `config` (Localizer.reconfigured: the matchers shared, and the maps'
        wall trees: the server reconfigures the set for every request)."""
        out = MapSet({n: loc.reconfigured(config) for n, loc in self.localizers.items()}, self.served)
        out._walls = self._walls
        return out

    def matcher(self, method: str):
        """The method's matcher on every map (MethodError where one lacks it); the served map's."""
        for loc in self.localizers.values():
            loc.matcher(method)
        return self.localizers[self.served].matcher(method)

    def tracker(self, method: Optional[str] = None, on: str = ''):
        """The tracker of map `on` (default: the served map): the health watch's fit."""
        return self.localizers[on or self.served].tracker(method)

    def searched(self, maps: Optional[Sequence[str]]) -> list[str]:
        """The maps a request searches: `maps` (checked against the set) or every map."""
        if not maps:
            return self.names
        unknown = [m for m in maps if m not in self.localizers]
        if unknown:
            raise MapSetError(f'no map named {", ".join(unknown)} in the set (maps: {", ".join(self.names)})')
        return list(dict.fromkeys(maps))

    def localize(self, scan: Scan, method: Optional[str] = None, angle_step_deg: Optional[float] = None,
                 progress: Optional[ProgressFn] = None, base_T_laser: Optional[Rigid2D] = None,
                 prior: MapSetPrior = MapSetPrior()) -> LocalizationResult:
        """Localizer.localize over the maps `prior` names, within its region on each. The
        result's `map` and each hypothesis's `map` name the map."""
        return self.localize_points(scan_to_points(scan), method, angle_step_deg, progress, base_T_laser, prior)

    def localize_points(self, points, method: Optional[str] = None, angle_step_deg: Optional[float] = None,
                        progress: Optional[ProgressFn] = None, base_T_laser: Optional[Rigid2D] = None,
                        prior: MapSetPrior = MapSetPrior()) -> LocalizationResult:
        """`localize` for points already in the laser frame. With several maps and bnb, the
        maps are probed first (raced_leaves), then each is searched in full, the one with the
        best leaf first, every search seeded with the best leaf found anywhere so far."""
        t0 = time.perf_counter()
        names, region = self.searched(prior.maps), prior.region
        raced = len(names) > 1 and resolve_method(method or self.localizers[names[0]].config.method) == TRACKER_METHOD
        leaf = self.raced_leaves(points, names, base_T_laser, region) if raced else {n: 0.0 for n in names}
        best_leaf = max(leaf.values())
        results = {}
        for name in sorted(names, key=lambda n: -leaf[n]):
            k = names.index(name)
            part = None if progress is None else (
                lambda fraction, score, k=k: progress((k + fraction) / len(names), score))
            results[name] = tagged(self.localizers[name].localize_points(
                points, method, angle_step_deg, part, base_T_laser, SearchLimits(region, t0, best_leaf)), name)
            best_leaf = max(best_leaf, leaf_of(results[name]))
        return across({n: results[n] for n in names}, {n: self.localizers[n].tracker(method) for n in names},
                      time.perf_counter() - t0, self.common_fits(points, results, base_T_laser))

    def common_fits(self, points, results: dict[str, LocalizationResult], base_T_laser) -> Optional[dict]:
        """Each posed map's fit of the scan on a common footing, when the maps' resolutions
        differ (None when they agree: their scores already share one). A fit's field is
        sigma_cells wide in cells, so a map at 0.10 m explains the same returns more loosely
        than one at 0.05 m: the same floor mapped twice would win on its coarser copy. Here
        every map's best pose is scored with one field width in metres, the widest of the
        maps' (common_fit)."""
        posed = {n: r for n, r in results.items() if r.pose is not None and math.isfinite(r.score)}
        if len({self.localizers[n].map.resolution for n in posed}) < 2:
            return None
        sigma_m = max(self.localizers[n].config.bnb.sigma_cells * self.localizers[n].map.resolution for n in posed)
        fits = {}
        for name, result in posed.items():
            loc = self.localizers[name]
            if name not in self._walls:
                self._walls[name] = wall_tree(loc.map)
            laser = result.pose * (base_T_laser or loc.config.base_T_laser)
            fits[name] = common_fit(self._walls[name], laser.apply(points.points), sigma_m, loc.map.resolution)
        return fits

    def raced_leaves(self, points, names: list[str], base_T_laser, region) -> dict[str, float]:
        """The best leaf bnb's tree search finds on each map, in rounds: every map not yet done
        searched within a round's node budget (PROBE_NODES: a few hundred, then a few thousand
        expansions), the best leaf of any map so far as its incumbent. A map is done
        when its search ends within the budget. The map the scan fits finds a high leaf in an
        early round; with it as the incumbent, a map the scan does not fit is proved to hold
        no place in its band in a fraction of a search. The leaves only order the maps and
        seed the final searches (a leaf's score is reached by some place): they change the
        work, not the answer."""
        leaf, pending = {n: 0.0 for n in names}, list(names)
        for budget in PROBE_NODES:
            for name in sorted(pending, key=lambda n: -leaf[n]):
                leaf[name], done = self.localizers[name].probe(points, budget, max(leaf.values()), base_T_laser, region)
                if done:
                    pending.remove(name)
        return leaf


def wall_tree(occupancy_map) -> Optional[cKDTree]:
    """A KD-tree of the map's occupied cell centres in the world (None: no occupied cell)."""
    rows, cols = np.nonzero(occupancy_map.occupied)
    if not len(rows):
        return None
    return cKDTree(occupancy_map.frame.pixel_to_world(np.stack([cols, rows], axis=1)))


def common_fit(walls: Optional[cKDTree], world_points: np.ndarray, sigma_m: float, resolution: float) -> float:
    """The mean over the scan's returns of exp(-d^2 / 2 sigma^2), d the distance in metres
    from a return to the nearest wall cell (to its edge: a cell's centre lies half a cell
    from the surface the laser saw): a fit whose width does not depend on the map's
    resolution."""
    if walls is None or not len(world_points):
        return 0.0
    d, _ = walls.query(world_points, distance_upper_bound=4.0 * sigma_m + resolution)
    d = np.clip(d - 0.5 * resolution, 0.0, 4.0 * sigma_m)
    return float(np.mean(np.exp(-0.5 * (d / sigma_m) ** 2)))


def leaf_of(result: Optional[LocalizationResult]) -> float:
    """The best leaf score a result's bnb search found (0 without one)."""
    stats = getattr(result, 'search_stats', None)
    return float(getattr(stats, 'best_leaf', 0.0))


def tagged(result: LocalizationResult, name: str) -> LocalizationResult:
    hyps = [dataclasses.replace(h, map=name) for h in result.hypotheses]
    return dataclasses.replace(result, map=name, hypotheses=hyps)


def across(results: dict[str, LocalizationResult], trackers: dict, time_s: float,
           fits: Optional[dict] = None) -> LocalizationResult:
    """One answer from each map's: the best map's, kept confident only when no other map's
    best place comes within the lead it needs; the hypotheses of every map, best first.
    `fits`: each posed map's fit on a common footing (maps of different resolutions,
    MapSet.common_fits), compared instead of the maps' own scores."""
    if len(results) == 1:
        return dataclasses.replace(next(iter(results.values())), time_s=time_s)
    fit = (lambda r: fits[r.map]) if fits else (lambda r: r.score)
    posed = sorted((r for r in results.values() if r.pose is not None and math.isfinite(r.score)),
                   key=lambda r: -fit(r))
    hyps = sorted((h for r in results.values() for h in r.hypotheses), key=lambda h: -h.score)
    if not posed:
        return no_pose(results, time_s)
    best = posed[0]
    out = dataclasses.replace(best, hypotheses=hyps, time_s=time_s)
    if not best.success:
        return dataclasses.replace(out, message=f'{best.message} (map {best.map})')
    stopped = [n for n, r in results.items() if n != best.map and r.outcome == Outcome.SEARCH_INCOMPLETE]
    if stopped:
        return dataclasses.replace(out, outcome=Outcome.SEARCH_INCOMPLETE, confidence=0.0,
                                   message=f'search incomplete: localized on map {best.map}, but the search on map '
                                           f'{", ".join(stopped)} stopped before it could rule a better place out')
    rival = max((fit(r) for r in posed[1:]), default=0.0)
    need = trackers[best.map].lead_needed(fit(best))
    lead = (fit(best) - rival) / fit(best) if fit(best) > 0 else 0.0
    if rival > 0 and lead < need:
        other = next(r.map for r in posed[1:] if fit(r) == rival)
        return dataclasses.replace(out, outcome=Outcome.AMBIGUOUS,
                                   confidence=min(best.confidence, best.confidence * max(lead, 0.0) / need),
                                   message=f'ambiguous between maps: the best place of map {other} lies '
                                           f'{100 * max(lead, 0.0):.1f}% behind the best, on map {best.map} (a '
                                           f'confident answer needs a {100 * need:.0f}% lead); see the hypotheses')
    return dataclasses.replace(out, message=f'{best.message} (map {best.map}; the other maps\' best places lie '
                                            f'{100 * lead:.0f}% or more behind)')


def no_pose(results: dict[str, LocalizationResult], time_s: float) -> LocalizationResult:
    """No map gave a pose: `search incomplete` if any search stopped early (a map was not
    searched through), else the first map's outcome; the message says each map's."""
    first = next(iter(results.values()))
    stopped = [r for r in results.values() if r.outcome == Outcome.SEARCH_INCOMPLETE]
    pick = stopped[0] if stopped else first
    said = '; '.join(f'map {n}: {r.message}' for n, r in results.items())
    return dataclasses.replace(pick, message=f'no map gave a pose ({said})', time_s=time_s, map='')

