"""The branch-and-bound matcher in stages: options, grids (per-map precomputation),
kernels (compiled bounds and search loop), search (threads), refine, free_space,
verdict, and matcher (the wiring)."""
from .matcher import BranchAndBoundMatcher, warm_up
from .options import BranchAndBoundOptions, option_fields, option_range

__all__ = ['BranchAndBoundMatcher', 'BranchAndBoundOptions', 'option_fields', 'option_range', 'warm_up']
