"""REPORT.md and plots from the benchmark's rows."""
from __future__ import annotations

import math
import os
from collections import defaultdict

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..core.scan import scan_to_points  # noqa: E402
from ..core.transform import Rigid2D  # noqa: E402
from ..plot import plot_localization  # noqa: E402
from .soak import WARM_UP_GOALS  # noqa: E402

BASELINE = 'template_ccoeff'


def stats(rows: list[dict]) -> dict:
    times = np.array([r['time_s'] for r in rows if math.isfinite(r.get('time_s', float('nan')))])
    n = len(rows)
    return {'n': n,
            'ok': sum(r['ok'] for r in rows) / n if n else float('nan'),
            'ok_loose': sum(r['ok_loose'] for r in rows) / n if n else float('nan'),
            'top4': sum(r.get('top4_ok', False) for r in rows) / n if n else float('nan'),
            'marked_wrong': sum(r['success'] and not r['ok'] for r in rows) / n if n else float('nan'),
            'marked': sum(r['success'] for r in rows) / n if n else float('nan'),
            'median': float(np.median(times)) if len(times) else float('nan'),
            'p95': float(np.percentile(times, 95)) if len(times) else float('nan')}


def group(rows, key):
    out = defaultdict(list)
    for r in rows:
        out[key(r)].append(r)
    return out


def pct(v):
    return '–' if not math.isfinite(v) else f'{100 * v:.0f}%'


def secs(v):
    return '–' if not math.isfinite(v) else (f'{v:.3f}' if v < 1 else f'{v:.2f}')


def method_table(rows, label_fn, label_name, methods, baseline_rows=None) -> str:
    """One line per (label, method): success at both criteria, times, speed vs baseline."""
    lines = [f'| {label_name} | method | n | success 0.2 m/5° | success 0.5 m/10° | marked success but wrong '
             f'| median time [s] | p95 time [s] | time / baseline |',
             '|---|---|---|---|---|---|---|---|---|']
    for label, group_rows in sorted(group(rows, label_fn).items(), key=lambda kv: str(kv[0])):
        base = stats([r for r in group_rows if r['method'] == BASELINE and r.get('angle_step', 5) == 5])
        for m in methods:
            mr = [r for r in group_rows if r['method'] == m]
            if not mr:
                continue
            s = stats(mr)
            known = math.isfinite(base['median']) and base['median'] > 0
            ratio = f"{s['median'] / base['median']:.3f}" if known and math.isfinite(s['median']) else '–'
            lines.append(f'| {label} | {m} | {s["n"]} | {pct(s["ok"])} | {pct(s["ok_loose"])} '
                         f'| {pct(s["marked_wrong"])} | {secs(s["median"])} | {secs(s["p95"])} | {ratio} |')
    return '\n'.join(lines)


def search_share_table(rows, label_fn, label_name) -> str:
    """bnb's median time split into the search proper and the fixed work around it
    (scan tables, refinement, free-space check, covariance, verdict), beside 1% of the
    thesis baseline's median: what a localization may take to be 100x faster."""
    lines = [f'| {label_name} | n | bnb median [s] | search [s] | the rest [s] | rest share | baseline median [s] '
             f'| 1% of baseline [s] |', '|---|---|---|---|---|---|---|---|']
    for label, group_rows in sorted(group(rows, label_fn).items(), key=lambda kv: str(kv[0])):
        timed = [r for r in group_rows if r['method'] == 'bnb' and r.get('search_s') is not None
                 and math.isfinite(r.get('time_s', float('nan')))]
        if not timed:
            continue
        total = np.array([r['time_s'] for r in timed])
        search = np.array([r['search_s'] for r in timed])
        rest = total - search
        base = stats([r for r in group_rows if r['method'] == BASELINE and r.get('angle_step', 5) == 5])['median']
        lines.append(f'| {label} | {len(timed)} | {secs(float(np.median(total)))} | {secs(float(np.median(search)))} '
                     f'| {secs(float(np.median(rest)))} | {pct(float(np.median(rest / total)))} | {secs(base)} '
                     f'| {secs(base / 100)} |')
    return '\n'.join(lines) if len(lines) > 2 else ''


def cond_label(r):
    c = f'{r["fov"]}° / {r["range"]} m / Δα {r["angle_step"]:g}°'
    return c + (f' / clutter {r["clutter"]}' if r.get('clutter') else '')


def write_report(rows, meta, out, maps, trials) -> None:
    methods = sorted({r['method'] for r in rows}, key=lambda m: (m != BASELINE, m))
    by_suite = group(rows, lambda r: r['suite'])
    md = ['# global_loc benchmark' + (' (quick)' if meta['quick'] else ''), '',
          f'Command: `{meta["command"]}` — {len(rows)} localizations in {meta["wall_time_s"]} s with '
          f'{meta["jobs"]} worker process(es), {meta.get("threads", 1)} thread(s) each (cv2.setNumThreads: '
          f'OpenCV\'s threads and bnb\'s search threads).', '',
          '| machine | |', '|---|---|'] + [f'| {k} | {v} |' for k, v in meta['machine'].items()] + ['']
    md += ['Success: position error < 0.2 m and heading error < 5° (the thesis criterion), also 0.5 m / 10°. '
           '"Marked success but wrong": the result says `success` but misses 0.2 m / 5° (share of all trials). '
           f'"time / baseline": median time over the thesis baseline ({BASELINE}, Δα = 5°) on the same trials '
           'of the same run (< 1 is faster).', '',
           'Maps: ' + ', '.join(f'{n} ({v})' for n, v in meta['maps'].items()) + '.', '']
    benchmarks = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
                              'benchmarks')
    reading = os.path.join(benchmarks, 'READING.md')
    # the hand-written reading belongs to the committed report only
    if os.path.abspath(out) == os.path.join(benchmarks, 'results') and os.path.exists(reading):
        md += [open(reading).read(), '']

    if 'sim' in by_suite:
        sim = by_suite['sim']
        md += ['## Suite 2: simulated scans (pybullet Pioneer 3-DX, thesis §4.2)', '',
               'Scans from the pybullet simulator (0.01 m range noise, 1% dropouts) at seeded free poses, '
               'one factor varied at a time around 270° / 20 m / Δα 5°; "clutter 8": eight chairs, bins and '
               'people not in the map. All maps pooled:', '',
               method_table(sim, cond_label, 'condition', methods), '',
               'Per map, 270° / 20 m / Δα 5°:', '',
               method_table([r for r in sim if r['fov'] == 270 and r['range'] == 20 and r['angle_step'] == 5
                             and not r['clutter']], lambda r: r['map'], 'map', methods), '',
               '![success by factor](sim_factors.png)', '', '![time by map](sim_time.png)', '']
        share = search_share_table([r for r in sim if r['angle_step'] == 5], cond_label, 'condition')
        if share:
            md += ['Where bnb\'s time goes (medians over the trials; "the rest": building the scan\'s angle tables, '
                   'refining the peaks, the free-space check, the covariance and the verdict):', '', share, '']
        plot_sim(sim, methods, out)
    if 'cut' in by_suite:
        cut = by_suite['cut']
        md += ['## Suite 1: local maps cut from the map (thesis §4.1)', '',
               'The map\'s own wall surfaces within 3, 6 or 10 m of a seeded free pose, in the pose\'s frame: '
               'a perfect scan, the upper bound for each method.', '',
               method_table(cut, lambda r: f'r = {r["radius"]:.0f} m / Δα {r["angle_step"]:g}°', 'cut', methods), '',
               '![time against local map size](cut_time_vs_size.png)', '']
        plot_cut(cut, methods, out)
    if 'carmen' in by_suite:
        car = by_suite['carmen']
        filt = meta.get('carmen_filters', {})
        md += ['## Suite 3: real laser logs (CARMEN, held-out folds)', '',
               'Each log is cut into 5 time blocks; a scan is localized in the map (5 cm) built from the *other* '
               'four blocks, never in a map that contains it. Kept: scans whose reference pose lies on mapped '
               'free space and at least 70% of whose returns lie within two cells of a mapped wall.', '',
               '| log | scans | pose on free space | explained by map | sampled |', '|---|---|---|---|---|'] + \
              [f'| {log} | {c["scans"]} | {c["pose_on_free_space"]} | {c["explained_by_map"]} | {c["sampled"]} |'
               for log, c in filt.items()] + \
              ['', method_table(car, lambda r: r['log'], 'log', methods), '',
               'Top-4 (truth among the first four hypotheses), useful for ACES, which is nearly four-fold '
               'symmetric:', '',
               '| log | ' + ' | '.join(methods) + ' |', '|---|' + '---|' * len(methods)] + \
              [f'| {log} | ' + ' | '.join(pct(stats([r for r in lr if r['method'] == m])['top4']) for m in methods)
               + ' |' for log, lr in sorted(group(car, lambda r: r['log']).items())] + \
              ['', '![success per log](carmen.png)', '']
        plot_carmen(car, methods, out)
    if 'prior' in by_suite:
        md += prior_section(by_suite['prior'], out)
    if meta.get('relocalization'):
        md += relocalization_section(meta['relocalization'])
    if meta.get('soak'):
        md += soak_section(meta['soak'])
    if meta.get('scaling'):
        md += scaling_section(meta['scaling'], rows, out)
    md += failure_pictures(rows, trials, maps, out)
    with open(os.path.join(out, 'REPORT.md'), 'w') as f:
        f.write('\n'.join(md) + '\n')


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
             '| map | cells | free area [m²] | precompute [s] | grids [MB] | memory [MB] | bnb n | bnb success '
             '| bnb median [s] | bnb p95 [s] | baseline median [s] | baseline / bnb (median) |',
             '|---|---|---|---|---|---|---|---|---|---|---|---|']
    for name, p in pre.items():
        b, t = loc.get((name, 'bnb'), []), loc.get((name, BASELINE), [])
        sb, st = stats(b) if b else None, stats(t) if t else None
        ratio = f'{st["median"] / sb["median"]:.0f}×' if sb and st else '–'
        lines.append(f'| {name} | {p["cells"] / 1e6:.2f} M | {p["free_m2"]} | {p["precompute_s"]} | {p["grid_mb"]} '
                     f'| {p["memory_mb"]} | {len(b)} | {pct(sb["ok"]) if sb else "–"} '
                     f'| {secs(sb["median"]) if sb else "–"} | {secs(sb["p95"]) if sb else "–"} '
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
    fig.tight_layout()
    fig.savefig(os.path.join(out, 'scaling.png'), dpi=90)
    plt.close(fig)


def relocalization_section(rows) -> list[str]:
    """Kidnap and turn, watch, and the fits behind the supervisor's thresholds."""
    tests = group(rows, lambda r: r['test'])
    lines = ['## Keeping a robot localized (relocalization suite)', '',
             'Kidnap and turn: one scan at a seeded free pose; when the answer is ambiguous the robot turns in '
             'place (0.4 rad/s, one turn at most) and the hypotheses are followed with the simulated wheel '
             'odometry until one leads (else the turn\'s scans, fused into one view, are searched again). '
             '"success": marked success and right (0.2 m / 5°); "wrong": marked '
             'success but wrong.', '',
             '| map | n | single scan: success | wrong | ambiguous | after turning: success | wrong '
             '| turned until confident [°] (median) |', '|---|---|---|---|---|---|---|---|']
    for name, rr in sorted(group(tests.get('kidnap_turn', []), lambda r: r['map']).items()):
        n = len(rr)
        turned = [r['turned_deg'] for r in rr if r['resolved_success'] and not r['single_success']]
        lines.append(f'| {name} | {n} | {pct(sum(r["single_success"] and r["single_ok"] for r in rr) / n)} '
                     f'| {pct(sum(r["single_success"] and not r["single_ok"] for r in rr) / n)} '
                     f'| {pct(sum(r["single_outcome"] == "ambiguous" for r in rr) / n)} '
                     f'| {pct(sum(r["resolved_success"] and r["resolved_ok"] for r in rr) / n)} '
                     f'| {pct(sum(r["resolved_success"] and not r["resolved_ok"] for r in rr) / n)} '
                     f'| {np.median(turned):.0f} |' if turned else
                     f'| {name} | {n} | {pct(sum(r["single_success"] and r["single_ok"] for r in rr) / n)} '
                     f'| {pct(sum(r["single_success"] and not r["single_ok"] for r in rr) / n)} '
                     f'| {pct(sum(r["single_outcome"] == "ambiguous" for r in rr) / n)} '
                     f'| {pct(sum(r["resolved_success"] and r["resolved_ok"] for r in rr) / n)} '
                     f'| {pct(sum(r["resolved_success"] and not r["resolved_ok"] for r in rr) / n)} | – |')
    lines += ['', 'Watch: circling in the map\'s most open spot with a correct pose (lost alarms), then a kidnap '
              'with the believed pose left behind: simulated seconds until a confident pose is published '
              '(3 s of low fit, then the search).', '',
              '| map | minutes driven | lost alarms per hour | kidnap: pose published | right | seconds to pose |',
              '|---|---|---|---|---|---|']
    kidnaps = {r['map']: r for r in tests.get('kidnap_watch', [])}
    for r in sorted(tests.get('false_alarms', []), key=lambda r: r['map']):
        k = kidnaps.get(r['map'], {})
        lines.append(f'| {r["map"]} | {r["minutes"]:g} | {60 * r["alarms"] / r["minutes"]:.1f} '
                     f'| {k.get("published")} | {k.get("ok")} | {k.get("seconds_to_pose")} |')
    lines += ['', 'Fit (field score x (1 - share of beams through walls)) at the true pose and at a random free '
              'pose - what the supervisor\'s `lost_fit` (0.4) and `degraded_fit` (0.5) stand between:', '',
              '| scans | n | true: 1st pct | 5th | median | random: median | 95th | 99th |',
              '|---|---|---|---|---|---|---|---|']
    for source, rr in sorted(group(tests.get('fit', []), lambda r: r['source']).items()):
        t, x = np.array([r['true_fit'] for r in rr]), np.array([r['random_fit'] for r in rr])
        lines.append(f'| {source} | {len(rr)} | ' + ' | '.join(f'{v:.2f}' for v in (
            *np.percentile(t, [1, 5, 50]), *np.percentile(x, [50, 95, 99]))) + ' |')
    return lines + ['']


def bars(ax, groups: dict, methods, value, title, ylabel):
    labels = list(groups)
    width = 0.8 / max(len(methods), 1)
    for i, m in enumerate(methods):
        vals = [value([r for r in groups[g] if r['method'] == m]) for g in labels]
        ax.bar(np.arange(len(labels)) + i * width, vals, width, label=m)
    ax.set_xticks(np.arange(len(labels)) + 0.4 - width / 2)
    ax.set_xticklabels([str(g) for g in labels], fontsize=8)
    ax.set_title(title, fontsize=9)
    ax.set_ylabel(ylabel, fontsize=8)


def plot_sim(rows, methods, out):
    ok = lambda rs: stats(rs)['ok'] if rs else 0.0  # noqa: E731
    base = dict(fov=270, range=20, angle_step=5, clutter=0)

    def vary(key):
        keep = [r for r in rows if all(r[k] == v for k, v in base.items() if k != key)]
        return dict(sorted(group(keep, lambda r: r[key]).items()))

    fig, axes = plt.subplots(2, 2, figsize=(11, 7))
    for ax, (key, title) in zip(axes.ravel(), [('fov', 'field of view [deg] (20 m, Δα 5°)'),
                                               ('range', 'max range [m] (270°, Δα 5°)'),
                                               ('angle_step', 'Δα [deg] (270°, 20 m)'),
                                               ('clutter', 'clutter objects (270°, 20 m, Δα 5°)')], strict=True):
        bars(ax, vary(key), methods, ok, title, 'success (0.2 m / 5°)')
        ax.set_ylim(0, 1)
    axes[0, 0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(out, 'sim_factors.png'), dpi=100)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(10, 4))
    keep = [r for r in rows if all(r[k] == v for k, v in base.items())]
    bars(ax, dict(sorted(group(keep, lambda r: r['map']).items())), methods,
         lambda rs: stats(rs)['median'] if rs else 0, 'median time per localization, 270° / 20 m / Δα 5°', 'seconds')
    ax.set_yscale('log')
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(out, 'sim_time.png'), dpi=100)
    plt.close(fig)


def plot_cut(rows, methods, out):
    fig, ax = plt.subplots(figsize=(8, 5))
    for m in methods:
        for step, marker in ((5, 'o'), (15, 's')):
            g = group([r for r in rows if r['method'] == m and r['angle_step'] == step], lambda r: r['local_map_cells'])
            if not g:
                continue
            xs = sorted(g)
            ax.plot(xs, [stats(g[x])['median'] for x in xs], marker=marker, label=f'{m}, Δα {step}°')
    ax.set_xlabel('local map size [cells] (side = 2 x radius)')
    ax.set_ylabel('median time [s]')
    ax.set_xscale('log')
    ax.set_yscale('log')
    ax.legend(fontsize=7)
    ax.set_title('time against local map size (thesis figs. 4.7/4.8)', fontsize=9)
    fig.tight_layout()
    fig.savefig(os.path.join(out, 'cut_time_vs_size.png'), dpi=100)
    plt.close(fig)


def plot_carmen(rows, methods, out):
    fig, ax = plt.subplots(figsize=(8, 4))
    bars(ax, dict(sorted(group(rows, lambda r: r['log']).items())), methods,
         lambda rs: stats(rs)['ok'] if rs else 0, 'real logs, held-out folds', 'success (0.2 m / 5°)')
    ax.set_ylim(0, 1)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(os.path.join(out, 'carmen.png'), dpi=100)
    plt.close(fig)


def failure_pictures(rows, trials, maps, out, count=2) -> list[str]:
    """Pictures of typical failures of the baseline: wrong and marked successful first."""
    wrong = [r for r in rows if r['method'] == BASELINE and not r['ok'] and 'estimate' in r and r['suite'] != 'cut']
    wrong.sort(key=lambda r: (not r['success'], r['suite'], r['trial']))
    md = [f'## Typical failures of the thesis baseline ({BASELINE})', ''] if wrong else []
    for i, r in enumerate(wrong[:count]):
        t = trials[r['trial']]
        path = os.path.join(out, f'failure_{i + 1}.png')
        plot_localization(path, maps[t.map_name], scan_to_points(t.scan).points, Rigid2D(*r['estimate']), t.truth,
                          base_T_laser=t.base_T_laser,
                          title=f'{r["suite"]} / {r["map"]}: {BASELINE} {r["err_xy"]:.1f} m, '
                                f'{r["err_yaw_deg"]:.0f}° off, score {r["score"]:.2f}, success={r["success"]}')
        md += [f'![failure {i + 1}](failure_{i + 1}.png)', '',
               f'{BASELINE}, {r["suite"]} on {r["map"]}: {r["err_xy"]:.2f} m and {r["err_yaw_deg"]:.1f}° off, '
               f'confidence {r["confidence"]:.2f}, marked success: {r["success"]}.', '']
    return md
