"""The report's first screen: per localization suite, bnb against the thesis method -
success, confident-wrong, median and p95 time - and where the other suites' figures are."""
from __future__ import annotations

import math
import os

from .tables import BASELINE, ROWS, group, pct, read_rows, secs, stats

# What each suite's trials are, in one line (the sections below the summary say more).
SUITE_TRIALS = {
    'cut': 'local maps cut from the map (perfect scans), r = 3-10 m',
    'sim': 'pybullet scans, every condition pooled (field of view, range, clutter)',
    'carmen': 'real 180° laser logs, held-out maps',
    'prior': 'pybullet scans with a search prior, every radius pooled',
    'changed': 'ray-cast scans in a world changed since its map, levels 0-3 pooled',
    'unmapped': 'ray-cast scans, the map without its walls within 2 or 4 m of the robot (unknown or free), or an '
                'unknown room beside it',
    'sensors': 'front 180° / 270°, front + rear 270°, 3D lidar views at the same poses, pooled',
    'scaling': 'tiled building maps 500² to 6000²',
}
# Suites with their own figures (not one localization per trial), by the folder they are committed in.
OTHER_REPORTS = {'map_set': 'which map am I on: a map set, identical floors (suite maps)',
                 'relocalization': 'keeping a robot localized', 'follow': 'settling by motion on real logs',
                 'soak': 'real server processes under faults', 'one_job': 'one localization at a time, every core',
                 'big_map': 'the 6000² tiled building', 'tail': "the search's slow end against its targets",
                 'faults': 'runtime changes against the real server: wrong poses published, hangs, recovery'}


def comparable(rows: list[dict]) -> list[dict]:
    """Localization rows, the thesis method at its own Δα of 5° (the other steps are its variants)."""
    return [r for r in rows if r.get('method') and 'ok' in r and 'success' in r and r.get('kind', 'localize') ==
            'localize' and (r['method'] != BASELINE or r.get('angle_step', 5) == 5)]


def raw_view(rows: list[dict]) -> list[dict]:
    """A checked thesis matcher's rows as its own verdict had them (the thesis's numbers);
    rows without a raw verdict (nothing proposed, so nothing checked, or older runs) as they are."""
    return [{**r, 'success': r.get('raw_success', r['success']), 'ok': r.get('raw_ok', r['ok'])} for r in rows]


def cells(s: dict) -> list[str]:
    return [pct(s['ok']), pct(s['marked_wrong']), secs(s['median']), secs(s['p95'])] if s['n'] else ['–'] * 4


def summary_line(suite: str, rows: list[dict], where: str, trials: str = '') -> str:
    bnb = stats([r for r in rows if r['method'] == 'bnb'])
    thesis_rows = [r for r in rows if r['method'] == BASELINE]
    thesis, raw = stats(thesis_rows), stats(raw_view(thesis_rows))
    faster = (f"{thesis['median'] / bnb['median']:.0f}×" if bnb['n'] and thesis['n'] and bnb['median'] > 0
              and math.isfinite(thesis['median']) else '–')
    return ' | '.join(['', f'{suite}{where}', trials or SUITE_TRIALS[suite], str(bnb['n']), *cells(bnb),
                       str(thesis['n']), *cells(raw)[:2], *cells(thesis), faster, '']).strip()


def thesis_section(rows: list[dict]) -> list[str]:
    """Each thesis matcher per suite, its own verdict ("raw": the thesis's numbers) and the
    one the server publishes (checked on the map, matchers/verify.py)."""
    thesis = [r for r in comparable(rows) if r['method'] != 'bnb' and r.get('angle_step', 5) == 5]
    if not thesis:
        return []
    lines = ['## The thesis matchers (and features), raw and checked', '',
             'Raw: the matcher\'s own verdict (the best leads the next by 1%), as the thesis reported it. '
             'Checked: the same hypotheses refined and judged by bnb\'s verdict with the rest of the map searched '
             'for a rival (`core/matchers/verify.py`) - what the server publishes. Times include the check.', '',
             '| suite | method | n | raw success | raw confident-wrong | checked success | checked confident-wrong '
             '| median [s] | p95 [s] |', '|---' * 9 + '|']
    for (suite, method), rr in sorted(group(thesis, lambda r: (r['suite'], r['method'])).items()):
        raw, checked = stats(raw_view(rr)), stats(rr)
        lines.append(f'| {suite} | {method} | {checked["n"]} | {pct(raw["ok"])} | {pct(raw["marked_wrong"])} '
                     f'| {pct(checked["ok"])} | {pct(checked["marked_wrong"])} | {secs(checked["median"])} '
                     f'| {secs(checked["p95"])} |')
    return lines + [''] + build_table(thesis)


def build_table(rows: list[dict]) -> list[str]:
    """Each proposing matcher's precomputation per map (the worker's first build of it): seconds,
    and the megabytes it keeps where the matcher counts them (`nbytes`)."""
    built = [r for r in rows if r.get('build_s') is not None]
    if not built:
        return []
    lines = ['Precomputation per map (built with the map, once per worker process; "kept": what the matcher '
             'holds for the search, where it counts it):', '',
             '| map | method | cells | build [s] | kept [MB] | bytes a cell |', '|---' * 6 + '|']
    for (name, method), rr in sorted(group(built, lambda r: (r['map'], r['method'])).items()):
        kept, cells = rr[0].get('build_mb'), rr[0].get('map_cells')
        lines.append(f'| {name} | {method} | {f"{cells / 1e6:.2f} M" if cells else "–"} | {rr[0]["build_s"]:.2f} '
                     f'| {"–" if kept is None else f"{kept:.1f}"} '
                     f'| {f"{kept * 1e6 / cells:.0f}" if kept is not None and cells else "–"} |')
    return lines + ['']


def summary_section(rows: list[dict], results_dir: str | None = None) -> list[str]:
    """One line per localization suite of `rows`; with `results_dir` (the committed results),
    also the suites committed in its folders and links to the other suites' reports."""
    by_suite = group(comparable(rows), lambda r: r['suite'])
    lines = ['## Summary', '',
             f'Per suite: bnb (the default) against the thesis method ({BASELINE}, Δα 5°) on the same trials. '
             '"success": position within 0.2 m and heading within 5°; "confident-wrong": the answer says '
             '`success` but misses that (share of all trials); times per localization; "faster": the thesis '
             'method\'s median over bnb\'s. The thesis method\'s "raw" columns are its own verdict (the thesis\'s '
             'numbers), the others its answer checked on the map as the server publishes it (see the thesis '
             'matchers\' section).', '',
             '| suite | trials | bnb n | success | confident-wrong | median [s] | p95 [s] | thesis n | raw success '
             '| raw confident-wrong | success | confident-wrong | median [s] | p95 [s] | faster |', '|---' * 15 + '|']
    header_lines = len(lines)
    for suite in (s for s in SUITE_TRIALS if s in by_suite):
        lines.append(summary_line(suite, by_suite[suite], ''))
        if suite == 'sim':         # the thesis's own condition apart
            main = [r for r in by_suite[suite] if r['fov'] == 270 and r['range'] == 20 and not r['clutter']]
            lines.append(summary_line('sim 270° / 20 m', main, '', 'the same at 270° / 20 m without clutter'))
    links = []
    if results_dir is not None:
        for suite in SUITE_TRIALS:
            folder = os.path.join(results_dir, suite)
            if suite not in by_suite and os.path.exists(os.path.join(folder, ROWS)):
                committed = comparable(read_rows(folder))
                if committed:
                    lines.append(summary_line(suite, committed, f' ([run]({suite}/REPORT.md))'))
        links = [f'[{name}]({name}/REPORT.md) ({what})' for name, what in OTHER_REPORTS.items()
                 if os.path.exists(os.path.join(results_dir, name, 'REPORT.md'))]
    if len(lines) == header_lines:       # no localization suite in this run: its own section leads
        return []
    if links:
        lines += ['', 'Their own figures: ' + ', '.join(links) + '.']
    if results_dir is not None:
        lines += ['', 'What was decided from these figures, and what was measured and dropped: the decision '
                  'records, [docs/decisions](../../docs/decisions/README.md).']
    return lines + ['']


def meaning(rows: list[dict], notes: dict) -> list[str]:
    """What the run's figures are: the suites it ran, in a line each, and the criteria."""
    suites = [s for s in SUITE_TRIALS if any(r.get('suite') == s for r in rows) or notes.get(s)]
    suites += [s for s in OTHER_REPORTS if notes.get(s)]
    what = [f'- {s}: {SUITE_TRIALS.get(s) or OTHER_REPORTS[s]}' for s in suites]
    return ['What it means:', ''] + what + [
        '', 'A localization is right when its position is within 0.2 m and its heading within 5° of the truth '
        '(the thesis criterion; the tables also give 0.5 m / 10°). "Confident-wrong" (also "marked success but '
        'wrong"): the answer says `success` but is not right - the share of all trials, the figure a robot '
        f'pays for. "time / baseline": median time over the thesis baseline ({BASELINE}, Δα = 5°) on the same '
        'trials of the same run (< 1 is faster). Times are per localization, on the machine below.', '']
