"""bnb's verdict on an exhaustive search: a pure function of the distinct hypotheses and
the options - the one place the confidence rule is written in code (the README states
it for users). A search stopped short is judged in base.Matcher.judge."""
from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np
from numba import njit

from ...outcome import Outcome
from ..base import Candidate, Verdict
from .options import BranchAndBoundOptions


@njit(cache=True, nogil=True)
def searched_keep(fit, keep_ratio, min_confidence, band_allowance):
    """The band the search explores below its best leaf (of field score `fit`), as a
    ratio: nodes bounded at or above searched_keep x the best leaf are expanded. It is
    the lead a confident answer needs at this fit (min_confidence x (1 - keep_ratio) /
    explained, 5% at a full fit: a rival farther behind cannot change the outcome, only
    the confidence number) widened by band_allowance for refinement (a leaf is scored at
    a cell centre, the verdict at its refined pose: a rival's leaf may lie farther behind
    than its refined score - measured, not bounded:
    docs/decisions/0009-the-band-allowance-is-measured-not-bounded.md), and never wider than keep_ratio's band.
    Non-decreasing in fit, and fit x searched_keep rises with the fit, so a search
    pruning by the incumbent's band prunes no node the final band would keep."""
    explained = min(max((fit - 0.3) / 0.3, 0.0), 1.0)
    if explained <= 0.0:
        return keep_ratio
    return max(keep_ratio, 1.0 - min_confidence * (1.0 - keep_ratio) / explained - band_allowance)


# The most a peak's refined fit was seen above its leaf's score (+0.045, on a low-fit
# changed-world peak; docs/decisions/0009): what a narrow band's resume rule allows a place
# it did not score (matcher.resume_rule), and what a poor leaf may still gain
REFINED_GAIN = 0.05


def confident_fit(min_confidence: float) -> float:
    """The lowest leaf field score whose place could be judged localized: it must explain
    min_confidence of the scan ((fit - 0.3) / 0.3, judge's share) once refined, and a
    refined fit lies at most REFINED_GAIN above its leaf's."""
    return 0.3 + 0.3 * min_confidence - REFINED_GAIN


@njit(cache=True, nogil=True)
def keep_floor(space, best, n_points):
    """The lowest bound (raw, an integer: kernels.SearchSpace's band options) a node needs
    to be expanded, and a leaf to be kept, when the best leaf scores `best` (raw) on
    n_points points: the band below the best - or, while the best is too poor ever to be
    confident (below space.poor_fit, confident_fit's value; 0: no such floor), poor_fit
    itself, or with space.poor_band the band below a leaf at poor_fit. No leaf under
    poor_fit can be confident, and the band below it holds only the rivals of a leaf that
    reaches it: proving it below a poor best would only rank places that all answer `poor
    match`. With poor_band the floor is non-decreasing and continuous in best
    (searched_keep's note); without, it drops once the best reaches poor_fit, so a search
    floored so holds the nodes of the band below (search.ThreadedSearch.run)."""
    norm = 255.0 * max(n_points, 1)
    fit = best / norm
    lowest = space.poor_fit
    if fit < lowest:
        band = searched_keep(lowest, space.keep_ratio, space.min_confidence, space.band_allowance) \
            if space.poor_band else 1.0
        return np.int64(math.ceil(band * lowest * norm))
    return np.int64(math.ceil(searched_keep(fit, space.keep_ratio, space.min_confidence, space.band_allowance) * best))


def explained_share(fit: float) -> float:
    """How much of the scan the map explains at a field score: (fit - 0.3) / 0.3, in [0, 1]
    (searched_keep, compiled, writes the same)."""
    return float(np.clip((fit - 0.3) / 0.3, 0.0, 1.0))


def needed_lead(explained: float, options: BranchAndBoundOptions) -> float:
    """The lead over every other place, relative to the best, a confident answer needs
    where the map explains `explained` of the scan (5% at a full fit)."""
    return options.min_confidence * (1.0 - options.keep_ratio) / explained if explained > 0 else math.inf


# judge's tolerance on the lead: a place with no rival seen leads by exactly the lead needed
LEAD_TOLERANCE = 1e-9


# Headings this close to a half turn apart make two places each other's twin (a building
# symmetric under a half turn: the scan fits both)
TWIN_TOLERANCE = math.radians(20.0)


def rival_rank(c: Candidate) -> float:
    """The ranking score of another place as a rival of the best: what the map cannot rule
    out there. That is its optimistic score (capped at options.unknown_credit above its
    evidence when refined: peaks.PeakRefiner), since returns on unknown cells neither explain
    nor contradict it, less its beams through mapped walls, which the map does contradict.
    Its field score stays its evidence (`explained`): the field-score margin keeps the
    free-space check from vouching for the best alone, and a credit without that check
    would let a place whose beams cross walls tie the best."""
    if c.optimistic is None:
        return c.score
    return max(c.score, c.optimistic * (1.0 - (c.see_through or 0.0)))


def is_twin(best: Candidate, other: Candidate) -> bool:
    """Whether `other` is `best` turned by about a half turn (TWIN_TOLERANCE)."""
    turn = abs(math.remainder(other.laser_pose.yaw - best.laser_pose.yaw, 2 * math.pi))
    return abs(turn - math.pi) <= TWIN_TOLERANCE


def unscored_could_be_confident(fit_bound: float, best_fit: float, options: BranchAndBoundOptions) -> bool:
    """Whether a place the search has not scored yet, whose field score (refined) is at
    most fit_bound, could be judged localized against hypotheses whose best field score
    is best_fit: it would need to explain the scan (explained >= min_confidence) and to
    lead best_fit by the lead a confident answer needs at its fit (judge, either way it
    says localized). Both only grow with the place's fit, so checking fit_bound itself
    settles every place below it."""
    explained = explained_share(fit_bound)
    if explained <= 0.0 or explained < options.min_confidence:
        return False
    return fit_bound * (1.0 - needed_lead(explained, options) * (1.0 - LEAD_TOLERANCE)) >= best_fit


def judge(candidates: list[Candidate], options: BranchAndBoundOptions) -> Verdict:
    """The candidates are the distinct hypotheses, best first by ranking score (field
    score x (1 - see-through share)), each with its field score (`explained`).

    Confidence = (margin of the best over the next distinct place, relative to the best,
    over 1 - keep_ratio, the largest margin the search can see) x (how much of the scan
    the map explains: (ranking score - 0.3) / 0.3, clipped to [0, 1] - the field score
    counts an end point near a wall as explained even when its beam crosses another
    wall, which the map contradicts, so the best's share is its ranking score's). The
    margin is the smaller of the ranking score's and the field score's: the free-space
    check may reorder places but never vouches for one alone. Another place is measured by
    what the map cannot rule out (rival_rank): returns on unknown cells count for it,
    not against it, for up to bnb.unknown_credit of the scan - a place whose walls were
    never mapped stays a rival of its fully mapped twin. `localized` needs confidence >=
    min_confidence; otherwise `poor match` when the map explains too little of the scan,
    else `ambiguous`.

    Where the search looked only in the band a confident answer needs (searched_keep
    above keep_ratio: a good fit), a place it did not see lies at least that lead behind:
    a localized result then says its confidence is at least min_confidence, the most
    the band can vouch for."""
    opt = options
    if not candidates:
        return Verdict(Outcome.NO_MATCH, 0.0, 'bnb found no pose on free space')
    best, others = candidates[0], candidates[1:]
    ranks = [rival_rank(c) for c in others]
    fit = [best.explained, *(c.explained for c in others)]
    explained = explained_share(best.score)
    need = needed_lead(explained, opt)
    capped = searched_keep(fit[0], opt.keep_ratio, opt.min_confidence, opt.band_allowance) > opt.keep_ratio
    # No other peak found means none scored above `unseen` x best (in either score): the
    # band searched follows the leaves' field score, so it may be narrower than `need`
    unseen = 1.0 - needed_lead(explained_share(fit[0]), opt) if capped else opt.keep_ratio
    second = max(ranks) if others else unseen * best.score
    rival = max(fit[1:] + [unseen * max(fit)])
    rank_margin = (best.score - second) / best.score if best.score > 0 else 0.0
    fit_margin = (fit[0] - rival) / fit[0] if fit[0] > 0 else 0.0
    margin = min(rank_margin, fit_margin)
    conf = float(np.clip(margin / (1.0 - opt.keep_ratio), 0.0, 1.0)) * explained
    if capped and margin >= need * (1.0 - LEAD_TOLERANCE):
        return Verdict(Outcome.LOCALIZED, opt.min_confidence,
                       f'localized: confidence at least {opt.min_confidence:.2f} (the search looked for other '
                       f'places only within {100 * need:.0f}% of the best, the lead that needs)')
    if conf >= opt.min_confidence:
        return Verdict(Outcome.LOCALIZED, conf, 'localized')
    if explained < 1.0 and explained < opt.min_confidence:
        crossing = f' ({100 * best.see_through:.0f}% of its beams would pass through mapped walls)' \
            if best.see_through else ''
        return Verdict(Outcome.POOR_MATCH, conf, f'poor match: the map explains about {100 * best.score:.0f}% of the '
                                                 f'scan{crossing}')
    return ambiguous_verdict(best, others, ranks, LeadFigures(fit[0], need, margin, conf))


class LeadFigures(NamedTuple):
    """judge's figures, passed on rather than computed twice: the best's field score, the
    lead a confident answer needs, the margin it has and the confidence."""
    best_fit: float
    need: float
    margin: float
    conf: float


def ambiguous_verdict(best: Candidate, others: list[Candidate], ranks, figures: LeadFigures) -> Verdict:
    """judge's `ambiguous`, saying why: a rival only for what the map does not say, one
    whose beams cross walls, or places within the lead (`ranks`: the others' rival
    ranking scores); the closest named when it is the best's twin (a half turn)."""
    best_fit, need, margin, conf = figures
    closest = others[int(np.argmax(ranks))] if others else None
    twin = '; the closest is the best turned by about 180 deg (a symmetric place: its twin)' \
        if closest is not None and is_twin(best, closest) else ''
    # a rival only for what the map does not say (its evidence alone lies beyond the lead)
    if closest is not None and closest.score / best.score < 1.0 - need <= rival_rank(closest) / best.score:
        return Verdict(Outcome.AMBIGUOUS, conf,
                       f'ambiguous: another place, {100 * (closest.unknown or 0.0):.0f}% of its returns on cells the '
                       f'map does not know, could explain the scan as well as the best (what the map does say there '
                       f'agrees){twin}; see the hypotheses')
    rival_c = max(others, key=lambda c: c.explained) if others else None
    # a rival ranked behind only for its beams through walls (an exact twin ties: the next message)
    if rival_c is not None and rival_c.explained > best_fit and \
            (rival_c.see_through or 0.0) > (best.see_through or 0.0):
        return Verdict(Outcome.AMBIGUOUS, conf,
                       f'ambiguous: another place explains the scan as well or better, but '
                       f'{100 * (rival_c.see_through or 0.0):.0f}% of its beams would pass through walls '
                       f'({100 * (best.see_through or 0.0):.0f}% for the best){twin}; see the hypotheses')
    # the rivals: every other place within the lead a confident answer needs at this fit
    # (not only those within twice the margin: exact twins differ by rounding, ~1e-15)
    close = sum(r >= best.score * (1.0 - need) for r in ranks)
    return Verdict(Outcome.AMBIGUOUS, conf, f'ambiguous: {max(close, 1)} other place(s) within {100 * need:.0f}% '
                                            f'of the best (the closest {100 * max(margin, 0.0):.1f}% behind{twin}); '
                                            f'see the hypotheses')
