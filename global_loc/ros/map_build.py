"""The server's maps, prepared: each map of the set (or the map topic's one) with every
prepared method precomputed, in the map builder (core.map_slot) - a goal never builds one."""
from __future__ import annotations

import time

from ..core.localizer import Localizer
from ..core.map_set import MapSet


def build_map_set(load, config, logger) -> MapSet:
    """The maps `load()` gives (by name; the map topic's: one), each with every prepared method
    (`method`, bnb - the watch's fit - and `methods`) precomputed now; one that cannot be built
    on a map is refused to goals with the reason."""
    loaded = load()
    maps = loaded if isinstance(loaded, dict) else {'map': loaded}     # the map topic's: one map
    localizers = {}
    for name, occupancy_map in maps.items():
        t0 = time.perf_counter()
        localizers[name] = Localizer(occupancy_map, config.localizer, prepared=config.prepared)
        for reason in localizers[name].unavailable.values():
            logger.error(f'map {name}: {reason}; goals naming it are refused')
        ready = ', '.join(localizers[name].prepared())
        label = occupancy_map.source if len(maps) == 1 else f'{name} ({occupancy_map.source})'
        logger.info(f'map {label}: {occupancy_map.width} x {occupancy_map.height} cells at '
                    f'{occupancy_map.resolution} m; {ready} ready in {time.perf_counter() - t0:.2f} s')
    return MapSet(localizers, config.served_map if isinstance(loaded, dict) else 'map')
