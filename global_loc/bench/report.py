"""REPORT.md and plots from the benchmark's rows."""
from __future__ import annotations

import math
import os

import matplotlib

matplotlib.use('Agg')
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

from ..core.scan import scan_to_points  # noqa: E402
from ..core.transform import Rigid2D  # noqa: E402
from ..offline.plot import DrawnPoses, plot_localization  # noqa: E402
from .calibration import calibration_section  # noqa: E402
from .changed import changed_section  # noqa: E402
from .follow import follow_section  # noqa: E402
from .maps import maps_section  # noqa: E402
from .sections import faults_section, prior_section, scaling_section, soak_section  # noqa: E402
from .sensors import sensors_section  # noqa: E402
from .summary import meaning, summary_section, thesis_section  # noqa: E402
from .tables import BASELINE, group, pct, save_figure, secs, stats  # noqa: E402
from .tail import tail_section  # noqa: E402
from .unmapped import unmapped_section  # noqa: E402

BENCHMARKS = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))),
                          'benchmarks')
RESULTS = os.path.join(BENCHMARKS, 'results')


def method_table(rows, label_fn, label_name, methods) -> str:
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


def command_line(rows, meta) -> list[str]:
    count = f'{len(rows)} localizations in ' if rows else ''
    return [f'Command: `{meta["command"]}` — {count}{meta["wall_time_s"]} s with '
            f'{meta["jobs"]} worker process(es), {meta.get("threads", 1)} thread(s) each (cv2.setNumThreads: '
            f'OpenCV\'s threads and bnb\'s search threads).', '']


def machine(meta) -> list[str]:
    return (['| machine | |', '|---|---|'] + [f'| {k} | {v} |' for k, v in meta['machine'].items()] + [''] +
            ['Maps: ' + ', '.join(f'{n} ({v})' for n, v in meta['maps'].items()) + '.', ''])


def sim_section(sim, methods, out, plots: bool) -> list[str]:
    md = ['## Suite 2: simulated scans (pybullet Pioneer 3-DX, thesis §4.2)', '',
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
    if plots:
        plot_sim(sim, methods, out)
    return md


def cut_section(cut, methods, out, plots: bool) -> list[str]:
    if plots:
        plot_cut(cut, methods, out)
    return ['## Suite 1: local maps cut from the map (thesis §4.1)', '',
            'The map\'s own wall surfaces within 3, 6 or 10 m of a seeded free pose, in the pose\'s frame: '
            'a perfect scan, the upper bound for each method.', '',
            method_table(cut, lambda r: f'r = {r["radius"]:.0f} m / Δα {r["angle_step"]:g}°', 'cut', methods), '',
            '![time against local map size](cut_time_vs_size.png)', '']


def carmen_section(car, filters, methods, out, plots: bool) -> list[str]:
    if plots:
        plot_carmen(car, methods, out)
    return ['## Suite 3: real laser logs (CARMEN, held-out folds)', '',
            'Each log is cut into 5 time blocks; a scan is localized in the map (5 cm) built from the *other* '
            'four blocks, never in a map that contains it. Kept: scans whose reference pose lies on mapped '
            'free space and at least 70% of whose returns lie within two cells of a mapped wall.', '',
            '| log | scans | pose on free space | explained by map | sampled |', '|---|---|---|---|---|'] + \
           [f'| {log} | {c["scans"]} | {c["pose_on_free_space"]} | {c["explained_by_map"]} | {c["sampled"]} |'
            for log, c in filters.items()] + \
           ['', method_table(car, lambda r: r['log'], 'log', methods), '',
            'Top-4 (truth among the first four hypotheses), useful for ACES, which is nearly four-fold '
            'symmetric:', '',
            '| log | ' + ' | '.join(methods) + ' |', '|---|' + '---|' * len(methods)] + \
           [f'| {log} | ' + ' | '.join(pct(stats([r for r in lr if r['method'] == m])['top4']) for m in methods)
            + ' |' for log, lr in sorted(group(car, lambda r: r['log']).items())] + \
           ['', '![success per log](carmen.png)', '']


def write_report(rows, meta, out, maps, trials) -> None:
    """REPORT.md (and its plots) in `out`. Without maps and trials (a report written again
    from committed rows) the plots and failure pictures already there are kept, not drawn."""
    plots = trials is not None
    methods = sorted({r['method'] for r in rows}, key=lambda m: (m != BASELINE, m))
    by_suite = group(rows, lambda r: r['suite'])
    committed = os.path.abspath(out) == RESULTS      # the committed report also lists the suites' folders
    sections = []
    if 'sim' in by_suite:
        sections.append(sim_section(by_suite['sim'], methods, out, plots))
    if 'cut' in by_suite:
        sections.append(cut_section(by_suite['cut'], methods, out, plots))
    if 'carmen' in by_suite:
        sections.append(carmen_section(by_suite['carmen'], meta.get('carmen_filters', {}), methods, out, plots))
    if 'prior' in by_suite:
        sections.append(prior_section(by_suite['prior'], out))
    if 'changed' in by_suite:
        sections.append(changed_section(by_suite['changed'], out))
    if 'unmapped' in by_suite:
        sections.append(unmapped_section(by_suite['unmapped']))
    if 'sensors' in by_suite:
        sections.append(sensors_section(by_suite['sensors'], out, plots))
    for suite, section in (('map_set', maps_section), ('tail', tail_section),
                           ('relocalization', relocalization_section), ('follow', follow_section),
                           ('soak', soak_section), ('faults', faults_section)):
        if meta.get(suite):
            sections.append(section(meta[suite]))
    if meta.get('scaling'):
        sections.append(scaling_section(meta['scaling'], rows, out))
    if any(r.get('cov_d2') is not None for r in rows):
        sections.append(calibration_section(rows))
    # The report opens with its table (the summary, or the one suite's own), the command that
    # made it and what it means; the machine and the details follow.
    lead = summary_section(rows + meta.get('scaling', []), RESULTS if committed else None) or \
        (sections.pop(0) if sections else [])
    title = '# global_loc benchmark' + (' (quick)' if meta['quick'] else '')
    details = [line for section in sections for line in section] + failure_pictures(rows, trials, maps, out)
    md = [title, ''] + lead + command_line(rows, meta) + meaning(rows, meta) + machine(meta) + thesis_section(rows)
    if details:     # one screen of figures here; every suite's tables, plots and failures in DETAILS.md
        md += ['Each suite in full (every condition, map and log; plots; typical failures): [DETAILS.md](DETAILS.md).',
               '']
        with open(os.path.join(out, 'DETAILS.md'), 'w') as f:
            f.write('\n'.join([f'{title}: every suite in full', '', '[The report](REPORT.md)', ''] + details) + '\n')
    with open(os.path.join(out, 'REPORT.md'), 'w') as f:
        f.write('\n'.join(md) + '\n')


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
    save_figure(fig, out, 'sim_factors.png', dpi=100)
    fig, ax = plt.subplots(figsize=(10, 4))
    keep = [r for r in rows if all(r[k] == v for k, v in base.items())]
    bars(ax, dict(sorted(group(keep, lambda r: r['map']).items())), methods,
         lambda rs: stats(rs)['median'] if rs else 0, 'median time per localization, 270° / 20 m / Δα 5°', 'seconds')
    ax.set_yscale('log')
    ax.legend(fontsize=7)
    save_figure(fig, out, 'sim_time.png', dpi=100)


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
    save_figure(fig, out, 'cut_time_vs_size.png', dpi=100)


def plot_carmen(rows, methods, out):
    fig, ax = plt.subplots(figsize=(8, 4))
    bars(ax, dict(sorted(group(rows, lambda r: r['log']).items())), methods,
         lambda rs: stats(rs)['ok'] if rs else 0, 'real logs, held-out folds', 'success (0.2 m / 5°)')
    ax.set_ylim(0, 1)
    ax.legend(fontsize=7)
    save_figure(fig, out, 'carmen.png', dpi=100)


def failure_pictures(rows, trials, maps, out, count=2) -> list[str]:
    """Pictures of typical failures of the baseline: wrong and marked successful first."""
    wrong = [r for r in rows if r['method'] == BASELINE and not r['ok'] and 'estimate' in r
             and r['suite'] not in ('cut', 'sensors')]     # their trials are points, not scans to draw
    wrong.sort(key=lambda r: (not r['success'], r['suite'], r['trial']))
    md = [f'## Typical failures of the thesis baseline ({BASELINE})', ''] if wrong else []
    for i, r in enumerate(wrong[:count]):
        if trials is not None:        # else: the pictures already drawn for these rows
            t = trials[r['trial']]
            plot_localization(os.path.join(out, f'failure_{i + 1}.png'), maps[t.map_name],
                              scan_to_points(t.scan).points, DrawnPoses(Rigid2D(*r['estimate']), t.truth),
                              t.base_T_laser,
                              title=f'{r["suite"]} / {r["map"]}: {BASELINE} {r["err_xy"]:.1f} m, '
                                    f'{r["err_yaw_deg"]:.0f}° off, score {r["score"]:.2f}, success={r["success"]}')
        md += [f'![failure {i + 1}](failure_{i + 1}.png)', '',
               f'{BASELINE}, {r["suite"]} on {r["map"]}: {r["err_xy"]:.2f} m and {r["err_yaw_deg"]:.1f}° off, '
               f'confidence {r["confidence"]:.2f}, marked success: {r["success"]}.', '']
    return md
