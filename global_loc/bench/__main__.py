"""`python -m global_loc.bench [--quick] [--suites cut,sim,carmen,changed] [--jobs N]`

Runs the benchmark suites through the same Localizer the server uses, writes raw rows
(rows.jsonl), REPORT.md and PNG plots into the output folder (default
benchmarks/results/, or benchmarks/results/quick/ with --quick). Seeded: the same
command makes the same trials; timings are the machine's. `--report-only` writes REPORT.md
again from a folder's rows.jsonl and meta.json (a changed report without a rerun).
"""
from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import subprocess
import sys
import time

import cv2
import numpy as np
from tqdm import tqdm

from ..core.map_io import load_map_yaml
from .changed import changed_trials
from .faults import SCENARIOS, fault_rows
from .follow import follow_rows
from .relocalization import relocalization_rows
from .report import BASELINE, write_report
from .scaling import SIZES, scaling_rows
from .sensors import sensors_trials
from .soak import soak_rows, soak_summary
from .suites import (
    ANGLE_STEP_METHODS,
    METHODS,
    PRIOR_METHODS,
    carmen_trials,
    cut_trials,
    load_maps,
    prior_trials,
    shared_maps,
    sim_trials,
    symmetric_maps,
)
from .unmapped import unmapped_trials
from .worker import run_job, worker_init

# Suites whose rows are not one localization each: the report reads them apart.
NOTE_SUITES = ('relocalization', 'scaling', 'follow', 'soak', 'faults')
REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


def machine_info() -> dict:
    cpu = platform.processor()
    try:
        with open('/proc/cpuinfo') as f:
            cpu = next(line.split(':', 1)[1].strip() for line in f if line.startswith('model name'))
    except (OSError, StopIteration):
        pass
    import cv2
    import pybullet  # noqa: F401
    import scipy
    try:
        commit = subprocess.run(['git', 'rev-parse', 'HEAD'], cwd=REPO, capture_output=True, text=True).stdout.strip()
        dirty = bool(subprocess.run(['git', 'status', '--porcelain', '--untracked-files=no'], cwd=REPO,
                                    capture_output=True, text=True).stdout.strip())
    except OSError:
        commit, dirty = 'unknown', False
    from importlib.metadata import version
    return {'cpu': cpu, 'cores': os.cpu_count(), 'python': platform.python_version(),
            'numpy': np.__version__, 'opencv': cv2.__version__, 'scipy': scipy.__version__,
            'pybullet': version('pybullet'), 'git_commit': commit + (' (with uncommitted changes)' if dirty else ''),
            'date': time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}


def parse_args(argv):
    parser = argparse.ArgumentParser(prog='python -m global_loc.bench', description=__doc__.splitlines()[0])
    parser.add_argument('--quick', action='store_true', help='few poses and maps: a few minutes')
    parser.add_argument('--suites', default='cut,sim,carmen,prior,relocalization,scaling',
                        help='comma-separated: cut, sim, carmen, prior, relocalization, scaling; and changed (a '
                             'world changed since its map, three levels), unmapped (a map lacking the robot\'s '
                             'surroundings: bench/unmapped.py), sensors (front 180/270 deg, front + '
                             'rear, the 3D lidar: bench/sensors.py), soak (the real server and simulator '
                             'under faults), faults (runtime changes: bench/faults.py) and follow (resolution by '
                             'motion on the real logs), not in the default set')
    parser.add_argument('--soak-goals', type=int, default=0, help='goals of the soak suite (default 1000, quick 40)')
    parser.add_argument('--fault-runs', type=int, default=0, help='runs of each fault scenario (default 2, quick 1)')
    parser.add_argument('--fault-scenarios', default=','.join(SCENARIOS), help='comma-separated fault scenarios')
    parser.add_argument('--methods', default=','.join(METHODS))
    parser.add_argument('--jobs', type=int, default=os.cpu_count() or 1, help='worker processes')
    parser.add_argument('--shared', default=os.path.join(REPO, '..', 'shared', 'data'), help='shared/data folder')
    parser.add_argument('--out', default=None, help='output folder')
    parser.add_argument('--seed', type=int, default=2015)
    parser.add_argument('--poses', type=int, default=0, help='poses per map (default: 50, quick 6; suite 1: a fifth)')
    parser.add_argument('--scans-per-log', type=int, default=0, help='real scans per log (default: 100, quick 12)')
    parser.add_argument('--scaling-sizes', default='', help='comma-separated map sizes of the scaling suite, cells '
                                                           f'a side (default: {",".join(map(str, SIZES))}; quick: '
                                                           'the first three)')
    parser.add_argument('--report-only', action='store_true',
                        help='run nothing: write REPORT.md again from the output folder\'s rows.jsonl and '
                             'meta.json (the plots and failure pictures stay as they are)')
    return parser.parse_args(argv)


def build_trials(args, suites, maps, poses, notes) -> tuple[list, list, dict]:
    """The seeded trials of the localization suites (maps gains the held-out CARMEN maps);
    also the CARMEN trials and maps, which the relocalization suite reuses."""
    trials = []
    if 'cut' in suites:
        trials += cut_trials(maps, max(1, poses // 5) if args.poses else (3 if args.quick else 10), args.seed)
    seeded = (('sim', 'simulating scans with pybullet', sim_trials),
              ('prior', 'simulating scans for the search-prior suite', prior_trials),
              ('changed', 'ray-casting scans in changed worlds', changed_trials),
              ('unmapped', 'cutting the maps around the robot for the unmapped suite', unmapped_trials),
              ('sensors', 'simulating lasers and the 3D lidar for the sensors suite', sensors_trials))
    for suite, doing, make in seeded:
        if suite in suites:
            print(f'{doing} ...', file=sys.stderr)
            trials += make(maps, poses, args.seed)
    carmen, carmen_maps = [], {}
    if 'carmen' in suites or 'relocalization' in suites:
        print('building held-out maps from the CARMEN logs ...', file=sys.stderr)
        carmen, carmen_maps, notes['carmen_filters'] = carmen_trials(
            args.shared, args.scans_per_log or (12 if args.quick else 100), args.seed)
    if 'carmen' in suites:
        trials += carmen
        maps.update(carmen_maps)
    return trials, carmen, carmen_maps


def localize_all(trials, methods, maps, jobs: int, threads: int) -> list[dict]:
    """Every (trial, method) that applies, in `jobs` worker processes: one row each."""
    work = [(i, t, m) for i, t in enumerate(trials) for m in methods
            if not (m not in ANGLE_STEP_METHODS and t.condition.get('angle_step', 5) != 5)
            and (t.suite != 'prior' or m in PRIOR_METHODS)]
    rows = []
    # spawn, not fork: a child forked after OpenCV's thread pool started (the parent's map
    # building) can deadlock in its first OpenCV call (seen: cv2.setNumThreads in _worker_init).
    ctx = mp.get_context('spawn')
    with ctx.Pool(jobs, initializer=worker_init, initargs=(maps, threads)) as pool:
        for row in tqdm(pool.imap_unordered(run_job, work, chunksize=2), total=len(work), desc='localizations',
                        file=sys.stderr):
            rows.append(row)
    return rows


def run_other_suites(args, suites, methods, maps, poses, threads, carmen, carmen_maps, out, notes) -> None:
    """The suites that are not one localization per trial; their rows go into `notes`."""
    if 'relocalization' in suites:
        print('relocalization suite (kidnap and turn, watch) ...', file=sys.stderr)
        world = {**{n: m for n, m in maps.items() if '/' not in n}, **symmetric_maps()}
        notes['relocalization'] = relocalization_rows(world, max(2, poses // 5), 1.0 if args.quick else 10.0,
                                                      args.seed, carmen, carmen_maps)
    if 'scaling' in suites:
        print('scaling suite (tiled maps, precomputation in fresh processes) ...', file=sys.stderr)
        cv2.setNumThreads(threads)
        # the building the suite tiles (--quick's map set has no building_31: load it, else the office)
        building_yaml = shared_maps(args.shared).get('building_31')
        building = maps.get('building_31') or (load_map_yaml(building_yaml) if building_yaml else maps['office'])
        real = {n: m for n, m in maps.items() if '/' not in n or n.endswith('/fold0')}
        notes['scaling'] = scaling_rows(building, real, 3 if args.quick else max(5, poses // 4), args.seed,
                                        [m for m in methods if m in ('bnb', BASELINE)],
                                        [int(s) for s in args.scaling_sizes.split(',')] if args.scaling_sizes
                                        else SIZES[:3] if args.quick else SIZES)
    if 'follow' in suites:
        print('follow suite (resolution by motion on the CARMEN logs) ...', file=sys.stderr)
        notes['follow'] = follow_rows(args.shared, args.scans_per_log or (12 if args.quick else 100), args.seed)
    if 'soak' in suites:
        print('soak suite (server + simulator processes, faults) ...', file=sys.stderr)
        notes['soak'] = soak_rows(args.soak_goals or (40 if args.quick else 1000), args.seed,
                                  os.path.join(out, 'soak_logs'))
    if 'faults' in suites:
        print('fault suite (runtime changes against server + simulator processes) ...', file=sys.stderr)
        notes['faults'] = fault_rows(args.fault_runs or (1 if args.quick else 2), args.seed,
                                     os.path.join(out, 'fault_logs'), args.fault_scenarios.split(','))


def notes_from_rows(all_rows: list[dict]) -> tuple[list[dict], dict]:
    """rows.jsonl split back into the localization rows and the other suites' notes, as the
    report reads them (the soak suite as its summary)."""
    notes = {s: [r for r in all_rows if r.get('suite') == s] for s in NOTE_SUITES}
    notes = {s: rows for s, rows in notes.items() if rows}
    if 'soak' in notes:
        notes['soak'] = soak_summary(notes['soak'])
    return [r for r in all_rows if r.get('suite') not in NOTE_SUITES], notes


def report_again(out: str) -> int:
    """REPORT.md from the committed rows.jsonl and meta.json of `out`, nothing run."""
    with open(os.path.join(out, 'rows.jsonl')) as f:
        rows, notes = notes_from_rows([json.loads(line) for line in f if line.strip()])
    with open(os.path.join(out, 'meta.json')) as f:
        meta = {**json.load(f), **notes}
    write_report(rows, meta, out, maps=None, trials=None)
    print(f'wrote {out}/REPORT.md again from its rows ({len(rows)} localizations)', file=sys.stderr)
    return 0


def main(argv=None) -> int:
    args = parse_args(argv)
    out = args.out or os.path.join(REPO, 'benchmarks', 'results', 'quick' if args.quick else '')
    if args.report_only:
        return report_again(out)
    os.makedirs(out, exist_ok=True)
    suites, methods = args.suites.split(','), args.methods.split(',')
    if not os.path.isdir(args.shared):
        print(f'note: {args.shared} not found: real maps and logs are skipped', file=sys.stderr)
    t0 = time.time()
    machine = machine_info()   # before this run writes anything: the commit it runs from
    poses = args.poses or (6 if args.quick else 50)
    maps = load_maps(args.shared, args.quick)
    notes = {}
    trials, carmen, carmen_maps = build_trials(args, suites, maps, poses, notes)
    threads = max(1, (os.cpu_count() or 1) // args.jobs)     # per worker: its share of the cores
    rows = localize_all(trials, methods, maps, args.jobs, threads)
    run_other_suites(args, suites, methods, maps, poses, threads, carmen, carmen_maps, out, notes)
    with open(os.path.join(out, 'rows.jsonl'), 'w') as f:
        for row in rows + [r for s in NOTE_SUITES for r in notes.get(s, [])]:
            f.write(json.dumps(row) + '\n')
    meta = {'machine': machine, 'command': 'python -m global_loc.bench ' + ' '.join(argv or sys.argv[1:]),
            'jobs': args.jobs, 'threads': threads, 'wall_time_s': round(time.time() - t0, 1), 'quick': args.quick,
            'maps': {n: f'{m.width} x {m.height} cells at {m.resolution} m' for n, m in maps.items() if '/' not in n},
            **{k: v for k, v in notes.items() if k not in NOTE_SUITES}}
    with open(os.path.join(out, 'meta.json'), 'w') as f:
        json.dump(meta, f, indent=1)
    if 'soak' in notes:
        notes['soak'] = soak_summary(notes['soak'])
    write_report(rows, {**meta, **notes}, out, maps, trials)
    print(f'wrote {out}/REPORT.md ({len(rows)} localizations in {meta["wall_time_s"]} s)', file=sys.stderr)
    return 0


if __name__ == '__main__':
    sys.exit(main())
