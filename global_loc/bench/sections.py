"""Report sections of the search-prior, soak, fault and scaling suites."""
from __future__ import annotations

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from .soak import WARM_UP_GOALS  # noqa: E402
from .tables import BASELINE, group, pct, save_figure, secs, stats  # noqa: E402


def prior_section(rows, out) -> list[str]:
    """Success and time per prior radius, and the time against the same method without one."""
    lines = ['## Search priors', '',
             '270° / 20 m pybullet scans; each scan localized with no prior and within a disc of the given radius '
             'around a point up to half the radius from the truth (heading free). "area": the disc over the '
             'map\'s free area (median over maps). "time / no prior": median time over the same method\'s '
             'median without a prior, same scans.', '',
             '| method | prior radius [m] | n | area | success 0.2 m/5° | marked success but wrong | median time [s] '
             '| p95 time [s] | time / no prior |', '|---|---|---|---|---|---|---|---|---|']
    for method, mr in sorted(group(rows, lambda r: r['method']).items()):
        whole = stats([r for r in mr if r['prior_radius'] == 0])['median']
        for radius, rr in sorted(group(mr, lambda r: r['prior_radius']).items(), key=lambda kv: -kv[0] or -1e9):
            s = stats(rr)
            area = float(np.median([r['area_share'] for r in rr]))
            lines.append(f'| {method} | {radius:g} | {s["n"]} | {"whole map" if not radius else pct(area)} '
                         f'| {pct(s["ok"])} | {pct(s["marked_wrong"])} | {secs(s["median"])} | {secs(s["p95"])} '
                         f'| {s["median"] / whole:.3f} |')
    return lines + ['']


def soak_section(s: dict) -> list[str]:
    """The soak suite's figures (bench/soak.py says what it runs)."""
    def f(v, unit=''):
        return '–' if v is None else (f'{v:.3f}{unit}' if isinstance(v, float) else f'{v}{unit}')
    return ['## Soak and faults (real server and simulator processes)', '',
            f'{s["goals"]} goals against `ros2 run global_loc server` (max_search_s 1 s) and the simulator node '
            '(office, 40 Hz x 1081 beams): plain bnb goals with a kidnap before every 10th, goals ending at the '
            'search limit (template matcher, 0.05° step), cancels at random moments, two clients at once, and a '
            f'SIGTERM mid-goal followed by a restart at goals {s["restart_goals"]}. RSS of the longest-running '
            f'server process ({s["rss_goals"]} goals after its first {WARM_UP_GOALS}); growth from then to its '
            f'last goal for each server process that ran more than {WARM_UP_GOALS}: {s["rss_growth_pct"]} %.', '',
            '| figure | value |', '|---|---|',
            f'| plain goals: answered / success / success and right / success but wrong | {s["answered"]} of '
            f'{s["plain"]} / {s["success"]} / {s["success_right"]} / {s["success_wrong"]} |',
            f'| /initialpose messages / wrong (> 0.2 m or 5° off the true pose) | {f(s["initialposes"])} / '
            f'{f(s["wrong_initialposes"])} |',
            f'| server RSS start / middle / end / max [MB] | {f(s["rss_start_mb"])} / {f(s["rss_middle_mb"])} / '
            f'{f(s["rss_end_mb"])} / {f(s["rss_max_mb"])} |',
            f'| cancel goals / ended by the cancel: latency median / p95 / max [s] / unanswered | '
            f'{s["cancel_goals"]} / {s["cancels"]}: {f(s["cancel_median_s"])} / {f(s["cancel_p95_s"])} / '
            f'{f(s["cancel_max_s"])} / {s["cancels_unanswered"]} |',
            f'| goal latency, median of the first / last 100 plain goals [s] | {f(s["latency_first100_median_s"])} '
            f'/ {f(s["latency_last100_median_s"])} |',
            f'| goals at the search limit: n / answered `search incomplete` | {s["limited"]} / '
            f'{s["limited_incomplete"]} |',
            f'| concurrent pairs | {s["concurrent"]} |',
            f'| SIGTERM mid-goal + restart: n / goal answered / slowest exit [s] / exit codes | {s["restarts"]} / '
            f'{s["restart_answered"]} / {f(s["exit_max_s"])} / {s["exit_codes"]} |',
            f'| crashes (server or simulator) | {s["crashes"]} |', '']


def faults_summary(rows: list[dict]) -> list[dict]:
    """Per scenario, in the order of the rows: the figures of the fault suite's table."""
    out = []
    for name in dict.fromkeys(r['scenario'] for r in rows):
        rr = [r for r in rows if r['scenario'] == name]
        rec = [r['recovery_s'] for r in rr if r['recovery_s'] is not None]
        out.append({'scenario': name, 'runs': len(rr), **{k: sum(r[k] for r in rr) for k in (
            'goals', 'answered', 'poses', 'wrong_poses', 'unchecked_poses', 'wrong_results', 'hangs', 'tracebacks')},
            **{k: sum(r.get(k, 0) for r in rr) for k in ('crashes', 'outlived', 'nonfinite_poses')},
            'cancel_max_s': max((r.get('cancel_max_s', 0.0) for r in rr), default=0.0),
            'recovered': len(rec), 'recovery_median_s': float(np.median(rec)) if rec else None,
            'recovery_max_s': max(rec) if rec else None, 'errors': sum(r.get('error') is not None for r in rr)})
    return out


def faults_section(rows: list[dict]) -> list[str]:
    """The fault suite's table (bench/faults.py says what each scenario does)."""
    def s_(v):
        return '–' if v is None else f'{v:.2f}'
    lines = ['## Runtime changes (fault suite: real server and simulator processes)', '',
             'Each scenario scripted against `ros2 run global_loc server` and the simulator node (bench/faults.py); '
             'goals sent one after another during the fault. "wrong": an /initialpose farther than 0.2 m / 5° '
             '(core.transform.pose_correct) from /sim/true_pose at the pose\'s stamp (the scan\'s); "wrong results": '
             'goals answered `localized` with such a pose. "hangs": a goal unanswered 20 s after it was sent, a '
             'service call unanswered in 15 s, a process not ended 10 s after its signal. "recovery": from the end '
             'of the fault (the last thing the scenario did) to the next right localization (a goal, a published '
             'pose, or the stand-in localizer taking one). "crashes": the server exited before the run\'s end; '
             '"outlived": goals in flight when a deactivate was sent, answered after it was, not `canceled`; '
             '"non-finite": poses with a NaN or inf coordinate, published or in a result; "slowest cancel": '
             'from a cancel request to the goal\'s result.', '',
             '| scenario | runs | goals answered | poses published | wrong poses | wrong results | hangs '
             '| recovered | recovery median / max [s] | tracebacks in logs | run errors | crashes | outlived '
             '| non-finite | slowest cancel [s] |',
             '|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|']
    for s in faults_summary(rows):
        lines.append(f'| {s["scenario"]} | {s["runs"]} | {s["answered"]} of {s["goals"]} | {s["poses"]} '
                     f'| {s["wrong_poses"]} | {s["wrong_results"]} | {s["hangs"]} | {s["recovered"]} of {s["runs"]} '
                     f'| {s_(s["recovery_median_s"])} / {s_(s["recovery_max_s"])} | {s["tracebacks"]} '
                     f'| {s["errors"]} | {s["crashes"]} | {s["outlived"]} | {s["nonfinite_poses"]} '
                     f'| {s["cancel_max_s"]:.2f} |')
    total = faults_summary([{**r, 'scenario': 'all'} for r in rows])[0] if rows else None
    if total:
        lines.append(f'| **all** | {total["runs"]} | {total["answered"]} of {total["goals"]} | {total["poses"]} '
                     f'| **{total["wrong_poses"]}** | {total["wrong_results"]} | **{total["hangs"]}** '
                     f'| {total["recovered"]} of {total["runs"]} | {s_(total["recovery_median_s"])} / '
                     f'{s_(total["recovery_max_s"])} | {total["tracebacks"]} | {total["errors"]} '
                     f'| **{total["crashes"]}** | **{total["outlived"]}** | **{total["nonfinite_poses"]}** '
                     f'| {total["cancel_max_s"]:.2f} |')
    return lines + ['']


def scaling_section(rows, all_rows, out) -> list[str]:
    """Time per localization and precomputation against free area: tiled maps and the run's real maps."""
    pre = {r['map']: r for r in rows if r['kind'] == 'precompute'}
    loc = group([r for r in rows if r['kind'] == 'localize'], lambda r: (r['map'], r['method']))
    # the real maps' localizations come from the sim (270 deg / 20 m) and carmen suites of the same run
    for r in all_rows:
        if r['suite'] == 'sim' and r['fov'] == 270 and r['range'] == 20 and r['angle_step'] == 5 and not r['clutter']:
            loc.setdefault((r['map'], r['method']), []).append(r)
        elif r['suite'] == 'carmen':
            loc.setdefault((r['map'].split('/')[0] + '/fold0', r['method']), []).append(r)
    lines = ['## Scaling: map size, free area, time', '',
             'building_31 (5 cm) cut to 500² cells and tiled to 1000², 2000², 4000², each tile with its own random '
             'boxes; ray-cast 270° / 20 m scans at seeded free poses. Real maps: the run\'s shared maps (sim '
             'suite, 270° / 20 m) and the CARMEN logs (all folds\' scans; precomputation of fold 0\'s map). '
             f'Precomputation in a fresh process: seconds, the grids, and the peak memory\'s rise. {BASELINE} is '
             'run until one localization takes a minute ("–": not run).', '',
             '| map | cells | free area [m²] | precompute [s] | grids [MB] | memory [MB] | peak [MB] | bnb n '
             '| bnb success | bnb median [s] | bnb p95 [s] | bnb budget stops | baseline median [s] '
             '| baseline / bnb (median) |',
             '|---|---|---|---|---|---|---|---|---|---|---|---|---|---|']
    for name, p in pre.items():
        b, t = loc.get((name, 'bnb'), []), loc.get((name, BASELINE), [])
        sb, st = stats(b) if b else None, stats(t) if t else None
        ratio = f'{st["median"] / sb["median"]:.0f}×' if sb and st else '–'
        stops = sum(r.get('outcome') == 'search_incomplete' for r in b)
        lines.append(f'| {name} | {p["cells"] / 1e6:.2f} M | {p["free_m2"]} | {p["precompute_s"]} | {p["grid_mb"]} '
                     f'| {p["memory_mb"]} | {p.get("peak_mb", "–")} | {len(b)} | {pct(sb["ok"]) if sb else "–"} '
                     f'| {secs(sb["median"]) if sb else "–"} | {secs(sb["p95"]) if sb else "–"} | {stops} '
                     f'| {secs(st["median"]) if st else "–"} | {ratio} |')
    plot_scaling(pre, loc, out)
    return lines + ['', '![scaling](scaling.png)', '']


def plot_scaling(pre, loc, out):
    fig, (ax_t, ax_p) = plt.subplots(1, 2, figsize=(11, 4))
    tiled = [n for n in pre if n.endswith('^2')]
    for names, marker, label in ((tiled, 'o-', 'tiled building'), ([n for n in pre if n not in tiled], 's', 'real')):
        area = [pre[n]['free_m2'] for n in names]
        for method, colour in (('bnb', 'C0'), (BASELINE, 'C3')):
            have = [(a, stats(loc[n, method])) for a, n in zip(area, names, strict=True) if loc.get((n, method))]
            if have:
                xs = [a for a, _ in have]
                ax_t.plot(xs, [s['median'] for _, s in have], marker, color=colour, label=f'{method} median ({label})')
                if method == 'bnb':
                    ax_t.plot(xs, [s['p95'] for _, s in have], marker, color=colour, alpha=0.4,
                              label=f'bnb p95 ({label})')
        ax_p.plot(area, [pre[n]['precompute_s'] for n in names], marker, color='C2', label=f'seconds ({label})')
        ax_p.plot(area, [pre[n]['memory_mb'] / 100 for n in names], marker, color='C4',
                  label=f'memory / 100 MB ({label})')
    for ax, title in ((ax_t, 'time per localization [s]'), (ax_p, 'bnb precomputation')):
        ax.set_xscale('log')
        ax.set_yscale('log')
        ax.set_xlabel('free area [m²]')
        ax.set_title(title)
        ax.legend(fontsize=7)
    save_figure(fig, out, 'scaling.png')
