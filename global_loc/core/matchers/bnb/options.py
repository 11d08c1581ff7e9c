"""The branch-and-bound matcher's options: one dataclass, each field documented once in
its metadata, from which the server declares its `bnb.*` parameters and the CLI its
`--bnb-*` flags (`option_fields`)."""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass, field, fields

from ...limits import check_within
from ..base import DISTINCT_ANGLE, DISTINCT_M, HYPOTHESES


def _option(default, help_text: str, bounds: tuple):
    """An option: its default, its help and its bounds (inclusive), which the dataclass
    checks - so the server's `bnb.*` ranges, the CLI's `--bnb-*` flags and the Python
    callers refuse the same values."""
    return field(default=default, metadata={'help': help_text, 'range': bounds})


@dataclass(frozen=True)
class BranchAndBoundOptions:
    sigma_cells: float = _option(1.5, 'width of the likelihood field around occupied cells, cells', (0.1, 20.0))
    levels: int = _option(7, 'levels of the search tree: blocks of 1 .. 2^(levels-1) cells (1 .. 7)', (1, 7))
    max_points: int = _option(240, 'scan points kept after the one-cell voxel filter', (3, 100000))
    plane_memory_mb: float = _option(320.0, "MB the search's max-pooled planes may take: on a map where they would "
                                            'take more (above ~29 Mcells) the planes of blocks of 8 cells and more, '
                                            'then of 4, are stored at lower resolution until they fit (not below '
                                            'blocks of 2: best effort) - looser bounds, more nodes, the same leaves',
                                            (1e-3, 1e6))
    max_range: float = _option(30.0, 'm; farther returns are left out (the angle step shrinks with the '
                                     'largest range, and far returns are the least sure)', (0.1, 1e4))
    keep_ratio: float = _option(0.9, 'nodes bounded above keep_ratio x the best score are explored: every '
                                     'pose scoring that high is found (the hypotheses, the margin); the widest '
                                     'band, which band_allowance may narrow', (0.01, 0.999))
    band_allowance: float = _option(1.0, 'the search looks within the lead a confident answer needs (5% at a '
                                          'full fit) plus this, at most keep_ratio\'s band (verdict.searched_keep), '
                                          'then resumes with the whole band unless no place below could change a '
                                          'confident answer (matcher.resume_rule): the same answers as 1 (the '
                                          'default, always the whole band), no faster (docs/decisions/0016)',
                                    (0.0, 1.0))
    settle_slack: float = _option(1.0, "end the search early (never with a success) once no place it has not "
                                       "scored could make the answer confident, allowing this much for a pose's "
                                       'refined score above its search score (0.05: the most seen was +0.045); 1 '
                                       '(the default): never - an early ambiguous answer may lack the true place '
                                       '(docs/decisions/0012)', (0.0, 1.0))
    max_nodes: int = _option(400000, 'node expansions after which the search stops and says it was not exhaustive',
                             (1, 10 ** 9))
    hypotheses: int = _option(HYPOTHESES, 'distinct poses refined, judged and returned', (1, 100))
    distinct_m: float = _option(DISTINCT_M, 'm; poses closer than this (and distinct_angle) are one hypothesis: '
                                            'the one place distinctness is decided, before the verdict', (0.0, 1e3))
    distinct_angle: float = _option(DISTINCT_ANGLE, 'rad; poses closer than this (and distinct_m) are one '
                                                    'hypothesis', (0.0, math.pi))
    see_through_tolerance_cells: float = _option(3.0, "a return's beam is checked for walls up to this many "
                                                      'cells short of its end (noise, grazing beams)', (0.0, 100.0))
    unknown_credit: float = _option(1.0 / 3.0, 'share of the scan that may count as explained on unknown cells a '
                                               'beam can reach (a wall the map lacks): a place whose walls were '
                                               'never mapped stays a rival of its mapped twin (a second search '
                                               'after a confident answer); 0: unknown counts against a place as '
                                               'free space does - faster on maps mostly unexplored, but confidently '
                                               'wrong at the twin of a partly mapped place (docs/decisions/0020)',
                                    (0.0, 1.0))
    min_confidence: float = _option(0.5, 'confidence (see the verdict) a result needs to be a success, in (0, 1]',
                                    (0.001, 1.0))

    def __post_init__(self):
        for f in fields(self):      # a confidence of 0 would be a tie with another place: never a success
            value = getattr(self, f.name)
            if isinstance(value, bool) or not isinstance(value, numbers.Real):
                raise ValueError(f'bnb.{f.name} must be a number, got {value!r}')
            check_within(f'bnb.{f.name}', value, f.metadata['range'])
        if not (self.distinct_m > 0 and self.distinct_angle > 0):
            raise ValueError(f'bnb distinct_m and distinct_angle must be > 0, got {self.distinct_m}, '
                             f'{self.distinct_angle}')


def option_fields():
    """(name, type, default, help) of every option, in declaration order."""
    return [(f.name, type(f.default), f.default, f.metadata['help']) for f in fields(BranchAndBoundOptions)]


def option_range(name: str) -> tuple:
    """The option's (lowest, highest), both allowed."""
    return next(f.metadata['range'] for f in fields(BranchAndBoundOptions) if f.name == name)
