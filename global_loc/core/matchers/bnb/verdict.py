"""bnb's verdict on an exhaustive search: a pure function of the distinct hypotheses and
the options - the one place the confidence rule is written in code (the README states
it for users). A search stopped short is judged in base.Matcher.judge."""
from __future__ import annotations

import numpy as np

from ...outcome import Outcome
from ..base import Candidate, Verdict
from .options import BranchAndBoundOptions


def judge(candidates: list[Candidate], options: BranchAndBoundOptions) -> Verdict:
    """The candidates are the distinct hypotheses, best first by ranking score (field
    score x (1 - see-through share)), each with its field score (`explained`).

    Confidence = (margin of the best over the next distinct place, relative to the best,
    over 1 - keep_ratio, the largest margin the search can see) x (how much of the scan
    the map explains: (field score - 0.3) / 0.3, clipped to [0, 1]). The margin is the
    smaller of the ranking score's and the field score's: the free-space check may
    reorder places but never vouches for one alone. `localized` needs confidence >=
    min_confidence; otherwise `poor match` when the map explains too little of the scan,
    else `ambiguous`."""
    opt = options
    if not candidates:
        return Verdict(Outcome.NO_MATCH, 0.0, 'bnb found no pose on free space')
    best, others = candidates[0], candidates[1:]
    fit = [c.explained for c in candidates]
    # No other peak found means none scored above keep_ratio x best (in either score).
    second = others[0].score if others else opt.keep_ratio * best.score
    rival = max(fit[1:] + [opt.keep_ratio * max(fit)])
    rank_margin = (best.score - second) / best.score if best.score > 0 else 0.0
    fit_margin = (fit[0] - rival) / fit[0] if fit[0] > 0 else 0.0
    margin = min(rank_margin, fit_margin)
    explained = float(np.clip((fit[0] - 0.3) / 0.3, 0.0, 1.0))
    conf = float(np.clip(margin / (1.0 - opt.keep_ratio), 0.0, 1.0)) * explained
    if conf >= opt.min_confidence:
        return Verdict(Outcome.LOCALIZED, conf, 'localized')
    if explained < 1.0 and explained < opt.min_confidence:
        return Verdict(Outcome.POOR_MATCH, conf, f'poor match: the map explains about {100 * fit[0]:.0f}% of the scan')
    if fit_margin < 0 and others:
        rival_c = max(others, key=lambda c: c.explained)
        return Verdict(Outcome.AMBIGUOUS, conf,
                       f'ambiguous: another place explains the scan as well or better, but '
                       f'{100 * (rival_c.see_through or 0.0):.0f}% of its beams would pass through walls '
                       f'({100 * (best.see_through or 0.0):.0f}% for the best); see the hypotheses')
    # the rivals: every other place within the lead a confident answer needs at this fit
    # (not only those within twice the margin: exact twins differ by rounding, ~1e-15)
    need = opt.min_confidence * (1.0 - opt.keep_ratio) / explained
    close = sum(c.score >= best.score * (1.0 - need) for c in others)
    return Verdict(Outcome.AMBIGUOUS, conf, f'ambiguous: {max(close, 1)} other place(s) within {100 * need:.0f}% '
                                            f'of the best (the closest {100 * max(margin, 0.0):.1f}% behind); '
                                            f'see the hypotheses')
