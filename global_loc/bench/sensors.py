"""The sensors suite: the same seeded poses on several maps seen by a front
laser of 180° and of 270°, by front and rear 270° lasers together, and by the 3D lidar,
all cast by the pybullet simulator in the same world (extruded in 3D: the lidar's rings
see walls, low obstacles and the floor). Each trial's view is made as the server makes
it (core.view.merge_view, the cloud through core.cloud's parser) and localized by
Localizer.localize_points in the benchmark's workers."""
from __future__ import annotations

from functools import partial

import matplotlib
import numpy as np

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402

from ..core.cloud import cloud_xyz, pack_cloud  # noqa: E402
from ..core.map_io import OccupancyMap  # noqa: E402
from ..core.scan import ScanError, ScanPoints  # noqa: E402
from ..core.view import SensorReading, merge_view, reading_from_scan  # noqa: E402
from ..sim.laser import LaserConfig  # noqa: E402
from ..sim.lidar3d import Lidar3DConfig  # noqa: E402
from ..sim.raycast import sample_free_poses  # noqa: E402
from ..sim.robot import FRONT_LASER_MOUNT, LIDAR_MOUNT, REAR_LASER_MOUNT  # noqa: E402
from ..sim.simulator import Simulator  # noqa: E402
from .suites import Trial  # noqa: E402
from .tables import group, pct, save_figure, secs, stats  # noqa: E402

# The maps of the suite that the run has (office always; the others when shared/ has them).
SENSOR_MAPS = ('office', 'willow-2010-02-18-0.10', 'building_31')
SETUPS = ('front 180°', 'front 270°', 'front + rear 2 × 270°', '3D lidar')


def laser(fov: float) -> LaserConfig:
    """A laser of the sim suite's kind (0.5° beams, 20 m) with this field of view."""
    return LaserConfig(fov_deg=fov, num_beams=int(fov * 2) + 1, range_max=20.0)


def setup_views(sim: Simulator) -> dict:
    """Setup -> the view of the robot where it stands (core.view, as the server makes it)."""
    sim.laser = laser(180.0)
    scan_180 = sim.scan()
    sim.laser = laser(270.0)
    scan_270, scan_rear = sim.scan(), sim.rear_scan()
    cloud = cloud_xyz(pack_cloud(sim.lidar_points()))          # the PointCloud2 layout, parsed as received
    # readings made inside view_or_error: a scan with no return is that setup's unusable view
    front_180 = partial(reading_from_scan, '/scan', scan_180, FRONT_LASER_MOUNT)
    front_270 = partial(reading_from_scan, '/scan', scan_270, FRONT_LASER_MOUNT)
    rear = partial(reading_from_scan, '/scan_rear', scan_rear, REAR_LASER_MOUNT)
    lidar = partial(SensorReading, '/points', 0.0, cloud, LIDAR_MOUNT)
    readings = ({'/scan': front_180}, {'/scan': front_270}, {'/scan': front_270, '/scan_rear': rear},
                {'/points': lidar})
    return {name: view_or_error(r) for name, r in zip(SETUPS, readings, strict=True)}


def view_or_error(readings: dict):
    """The view of `readings` (sensor -> its reading, made here), or the ScanError saying
    why there is none (the server's answer then: UNUSABLE_SCAN, a failed trial). A sensor
    whose reading cannot be made (no return) is left out, as ros/sensors.make_view does."""
    made, reasons = {}, {}
    for name, reading in readings.items():
        try:
            made[name] = reading()
        except ScanError as e:
            reasons[name] = f'{type(e).__name__}: {e}'
    try:
        return merge_view(made, unread=reasons)
    except ScanError as e:        # ViewError too
        return e


def sensors_trials(maps: dict[str, OccupancyMap], poses_per_map: int, seed: int) -> list[Trial]:
    """Per map of SENSOR_MAPS the run has, seeded free poses; per pose one trial per setup."""
    trials = []
    for i, name in enumerate(n for n in SENSOR_MAPS if n in maps):
        m = maps[name]
        poses = sample_free_poses(m, poses_per_map, np.random.default_rng(seed + 400 + i), clearance=0.5)
        sim = Simulator(m, laser(270.0), seed=seed, rear_laser=laser(270.0), lidar=Lidar3DConfig())
        try:
            for pose in poses:
                sim.place(pose)
                truth = sim.true_pose()
                for setup, view in setup_views(sim).items():
                    condition = {'sensors': setup, 'angle_step': 5}
                    if isinstance(view, ScanError):      # no points: the worker's row says unusable_scan
                        trials.append(Trial('sensors', name, {**condition, 'view_points': 0, 'view_error': str(view)},
                                            truth, points=ScanPoints(np.empty((0, 2)), 0.0, 0)))
                        continue
                    trials.append(Trial('sensors', name, {**condition, 'view_points': len(view.points.points)}, truth,
                                        points=view.points, base_T_laser=view.base_T_laser))
        finally:
            sim.close()
    return trials


def sensors_table(rows: list[dict], by=lambda r: (r['sensors'],), label='sensors') -> list[str]:
    """Per method and setup: success, confident, confident-wrong, median and p95 time."""
    lines = [f'| method | {label} | n | view points (median) | success 0.2 m/5° | confident | confident-wrong '
             '| median time [s] | p95 time [s] |', '|---|---|---|---|---|---|---|---|---|']
    order = {s: i for i, s in enumerate(SETUPS)}
    for method, mr in sorted(group(rows, lambda r: r['method']).items()):
        # (map, setup) keys: by map, each map's setups in SETUPS' order
        for key, sr in sorted(group(mr, by).items(), key=lambda kv: (kv[0][:-1], order.get(kv[0][-1], len(order)))):
            s = stats(sr)
            points = [r['view_points'] for r in sr if 'view_points' in r]
            lines.append(f'| {method} | {": ".join(key)} | {s["n"]} | {int(np.median(points)) if points else "–"} '
                         f'| {pct(s["ok"])} | {pct(s["marked"])} | {pct(s["marked_wrong"])} | {secs(s["median"])} '
                         f'| {secs(s["p95"])} |')
    return lines


def sensors_section(rows: list[dict], out: str, plots: bool = True) -> list[str]:
    """The suite's tables (all maps pooled, then per map) and its plot."""
    maps = ', '.join(sorted({r['map'] for r in rows}))
    lines = ['## Several sensors', '',
             f'pybullet scans at the same seeded free poses on {maps}, in the world extruded in 3D (walls 2.5 m, '
             'obstacles of several heights), seen by: the front laser (180° or 270°, 0.5° beams, 20 m), the front '
             'and the rear 270° lasers merged into one view, and the 16-ring 3D lidar (±15°, 360°, 0.8° columns, '
             '30 m; its cloud packed as a PointCloud2 and parsed by core.cloud, cut to the 0.2-2 m band). Each '
             'view made by core.view.merge_view and localized by Localizer.localize_points, as the server does. '
             '"confident": the result says `success`; "confident-wrong": says `success` but misses 0.2 m / 5°; '
             '"view points": points the matchers get (a laser alone: its returns; merged: after the 5 cm voxel '
             'filter).', '', *sensors_table(rows), '', 'Per map:', '',
             *sensors_table(rows, lambda r: (r['map'], r['sensors']), 'map: sensors')]
    if plots:
        plot_sensors(rows, out)
    return lines + ['', '![success and time per sensor setup](sensors.png)', '']


def plot_sensors(rows: list[dict], out: str) -> None:
    fig, (ax_s, ax_t) = plt.subplots(1, 2, figsize=(11, 3.8))
    methods = sorted({r['method'] for r in rows})
    width = 0.8 / max(len(methods), 1)
    x = np.arange(len(SETUPS))
    for i, method in enumerate(methods):
        by_setup = group([r for r in rows if r['method'] == method], lambda r: r['sensors'])
        figures = [stats(by_setup.get(s, [])) for s in SETUPS]
        ax_s.bar(x + i * width, [100 * f['ok'] if f['n'] else 0 for f in figures], width, label=f'{method} success')
        ax_s.bar(x + i * width, [100 * f['marked_wrong'] if f['n'] else 0 for f in figures], width * 0.4,
                 color='k', alpha=0.6, label='confident-wrong (dark)' if i == 0 else None)
        ax_t.bar(x + i * width, [f['median'] if f['n'] else 0 for f in figures], width, label=f'{method} median')
        ax_t.plot(x + i * width, [f['p95'] if f['n'] else np.nan for f in figures], 'kv', alpha=0.6,
                  label='p95' if i == 0 else None)
    for ax, ylabel in ((ax_s, '% of trials'), (ax_t, 'time per localization [s]')):
        ax.set_xticks(x + 0.4 - width / 2)
        ax.set_xticklabels(SETUPS, fontsize=8)
        ax.set_ylabel(ylabel)
        ax.legend(fontsize=7)
    ax_t.set_yscale('log')
    save_figure(fig, out, 'sensors.png')
