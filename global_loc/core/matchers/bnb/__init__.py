"""The branch-and-bound matcher in stages: options, grids (per-map precomputation),
kernels (compiled bounds and search loop), search (threads), refine, free_space,
verdict, and matcher (the wiring)."""
from .matcher import BranchAndBoundMatcher, warm_up
from .options import BranchAndBoundOptions

__all__ = ['BranchAndBoundMatcher', 'BranchAndBoundOptions', 'warm_up']
