"""The changed-world suite: scans ray-cast in a world that differs from its map (boxes,
people near the robot, wall pieces removed: sim/changes.py) at levels 0 (the map itself)
to 3, localized against the unchanged map."""
from __future__ import annotations

import matplotlib
import numpy as np

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402

from ..core.map_io import OccupancyMap  # noqa: E402
from ..sim.changes import LEVELS, changed_world  # noqa: E402
from ..sim.laser import LaserConfig  # noqa: E402
from ..sim.raycast import sample_free_poses, simulate_scan  # noqa: E402
from .suites import Trial  # noqa: E402
from .tables import group, pct, save_figure, secs, stats  # noqa: E402

CHANGE_LEVELS = (0, *sorted(LEVELS))
# 270 deg / 20 m, 0.5 deg beams, 1 cm noise, 1% dropouts (the sim suite's laser)
LASER = LaserConfig(270.0, 541, range_max=20.0, noise_std=0.01, dropout=0.01)


def changed_trials(maps: dict[str, OccupancyMap], poses_per_map: int, seed: int) -> list[Trial]:
    """Per map, seeded free poses; per pose one world per level (level 0: the map)."""
    trials = []
    for i, (name, m) in enumerate(maps.items()):
        rng = np.random.default_rng(seed + 300 + i)
        for pose in sample_free_poses(m, poses_per_map, rng, clearance=0.5):
            for level in CHANGE_LEVELS:
                world = changed_world(m, level, pose, rng) if level else m
                trials.append(Trial('changed', name, {'change': level, 'angle_step': 5}, pose,
                                    scan=simulate_scan(world, pose, LASER, rng=rng)))
    return trials


def changed_section(rows: list[dict], out: str) -> list[str]:
    """Per method and level: success, confident, confident-wrong, time and expansions."""
    level_text = '; '.join(f'{k}: {c.boxes_per_100m2:g} boxes and {c.wall_gaps_per_100m2:g} wall gaps per 100 m² '
                           f'of floor, {c.people} people' for k, c in LEVELS.items())
    lines = ['## Changed world', '',
             'Ray-cast 270° / 20 m scans (1 cm noise, 1% dropouts) in a world that differs from its map, '
             f'localized against the unchanged map. Level 0: the map itself; {level_text} (boxes 0.3-1 m, none '
             'within 1.6 m of the robot; people 0.5 m wide within 0.6-3 m of it; gaps 0.8 m wide in walls '
             'facing free space). "confident": the result says `success`; "confident-wrong": says `success` '
             'but misses 0.2 m / 5°.', '',
             '| method | level | n | success 0.2 m/5° | confident | confident-wrong | median time [s] | p95 time [s] '
             '| median expansions | max expansions |', '|---|---|---|---|---|---|---|---|---|---|']
    for method, mr in sorted(group(rows, lambda r: r['method']).items()):
        for level, lr in sorted(group(mr, lambda r: r['change']).items()):
            s = stats(lr)
            exp = [r['expansions'] for r in lr if 'expansions' in r]
            lines.append(f'| {method} | {level} | {s["n"]} | {pct(s["ok"])} | {pct(s["marked"])} '
                         f'| {pct(s["marked_wrong"])} | {secs(s["median"])} | {secs(s["p95"])} '
                         f'| {int(np.median(exp)) if exp else "–"} | {max(exp) if exp else "–"} |')
    plot_changed(rows, out)
    return lines + ['', '![success and time against the level of change](changed.png)', '']


def plot_changed(rows: list[dict], out: str) -> None:
    fig, (ax_s, ax_t) = plt.subplots(1, 2, figsize=(10, 3.6))
    for method, mr in sorted(group(rows, lambda r: r['method']).items()):
        by_level = sorted(group(mr, lambda r: r['change']).items())
        levels = [level for level, _ in by_level]
        figures = [stats(lr) for _, lr in by_level]
        ax_s.plot(levels, [100 * s['ok'] for s in figures], 'o-', label=f'{method} success')
        ax_s.plot(levels, [100 * s['marked_wrong'] for s in figures], 'x--', label=f'{method} confident-wrong')
        ax_t.plot(levels, [s['median'] for s in figures], 'o-', label=f'{method} median')
        ax_t.plot(levels, [s['p95'] for s in figures], 's--', alpha=0.6, label=f'{method} p95')
    ax_s.set_ylabel('% of trials')
    ax_t.set_ylabel('time per localization [s]')
    ax_t.set_yscale('log')
    for ax in (ax_s, ax_t):
        ax.set_xlabel('level of change')
        ax.set_xticks(CHANGE_LEVELS)
        ax.legend(fontsize=7)
    save_figure(fig, out, 'changed.png')
