"""The benchmark's held-out localization on real CARMEN logs (the reader and the maps
built from a log: io/carmen.py): how much of a scan a map explains, and the folds of a
log whose maps leave each scan's own time block out."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..core.map_io import OccupancyMap
from ..io.carmen import GridCounts, LaserRecord, LogGrid, endpoints


def explained_fraction(occupancy_map: OccupancyMap, record: LaserRecord, cells: float = 2.0) -> float:
    """Fraction of the scan's returns that lie within `cells` cells of an occupied cell
    of the map at the reference pose (a scan the map cannot explain tests mapping)."""
    return _explained(occupancy_map, occupancy_map.distance_to_occupied(), record, cells)


def _explained(occupancy_map, dist, record, cells):
    pts, _ = endpoints(record.scan)
    if len(pts) == 0:
        return 0.0
    uv = occupancy_map.frame.cell_of(record.pose.apply(pts))
    inside = occupancy_map.frame.contains(uv)
    near = np.zeros(len(uv), bool)
    near[inside] = dist[uv[inside, 1], uv[inside, 0]] <= cells
    return float(near.mean())


@dataclass
class HeldOutScan:
    record: LaserRecord
    fold: int


def held_out_folds(records: list[LaserRecord], frame: LogGrid, folds: int = 5, min_explained: float = 0.7):
    """Split the log into `folds` time blocks; for each, the map from all *other* blocks
    and the block's scans that pass both filters (pose on mapped free space; at least
    `min_explained` of returns within two cells of a mapped wall).
    Returns ({fold: OccupancyMap}, [HeldOutScan], filter counts)."""
    blocks = np.array_split(np.arange(len(records)), folds)
    per_fold = [frame.counts([records[i] for i in b]) for b in blocks]
    total = per_fold[0]
    for c in per_fold[1:]:
        total = total + c
    maps, kept = {}, []
    stats = {'scans': len(records), 'pose_on_free_space': 0, 'explained_by_map': 0}
    for k, block in enumerate(blocks):
        others = GridCounts(total.hits - per_fold[k].hits, total.visits - per_fold[k].visits)
        m = frame.occupancy_map(others, f'held-out fold {k}')
        maps[k] = m
        dist = m.distance_to_occupied()
        for i in block:
            rec = records[i]
            if not m.is_free_at([[rec.pose.x, rec.pose.y]])[0]:
                continue
            stats['pose_on_free_space'] += 1
            if _explained(m, dist, rec, 2.0) < min_explained:
                continue
            stats['explained_by_map'] += 1
            kept.append(HeldOutScan(rec, k))
    return maps, kept, stats
