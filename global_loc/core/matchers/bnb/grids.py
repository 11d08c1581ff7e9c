"""Per map, built once: the likelihood field and the max-pooled planes the search's
bounds read, and which blocks of the map hold a free cell (Cartographer's
PrecomputationGridStack2D). The search only reads them."""
from __future__ import annotations

import cv2
import numpy as np

from ...map_io import OccupancyMap
from .kernels import FreeBlocks, Planes
from .options import BranchAndBoundOptions

MARGINS = (0, 1, 2, 3, 4, 6, 8, 12, 16, 24, 32)   # widenings (cells) for which grids are kept
PLANE_SHIFT_FROM = 3                   # planes of level h > this are stored at 1 / 2^(h - this)
                                       # resolution (see PrecomputationGridStack)


class PrecomputationGridStack:
    """Per map, built once: the likelihood field; per level and widening a uint8 plane
    whose cell holds the field's maximum over the block starting there and the widening
    around it (`grid_ids` picks one per point); per level, whether each block holds a
    free cell. Memory: `nbytes`.

    The search is bound by memory latency (a node reads ~200 scattered cells), so the
    planes are kept small: a level-h plane (windows of 2^h cells and more) is stored at
    1 / 2^shift[h] of the map's resolution, each stored cell the maximum over the
    2^shift x 2^shift cells it stands for. That widens each window by under 2^shift
    cells - a looser but still valid bound - and divides the memory the upper levels
    read by 4^shift. All planes are one flat array (`flat`, plane k from offsets[k]),
    read by the kernels through `planes` (kernels.Planes) as
    flat[offsets[k] + (y >> shift[h]) * plane_width[h] + (x >> shift[h])]."""

    def __init__(self, occupancy_map: OccupancyMap, options: BranchAndBoundOptions):
        self.options = options
        top = options.levels - 1
        # The widest plane must cover the top level's heading spread (else its bounds would
        # not be bounds), and the kernel's heap keys hold the level in 3 bits.
        most = max(n for n in range(1, 9) if self.margin(n - 1) <= MARGINS[-1])
        if not 1 <= options.levels <= most:
            raise ValueError(f'bnb levels must be 1 .. {most}, got {options.levels}')
        occupied = occupancy_map.occupied
        self.occupied = occupied.astype(np.uint8)     # for the free-space check
        # exp(-d^2 / 2 sigma^2) in place: a 4000^2 map's float32 temporaries are 64 MB each
        self.field = occupancy_map.distance_to_occupied().astype(np.float32, copy=False)
        np.square(self.field, out=self.field)
        self.field *= np.float32(-1.0 / (2.0 * options.sigma_cells ** 2))
        np.exp(self.field, out=self.field)
        p = (2 ** top) + 2 * int(self.margin(top)) + 2
        shift = np.array([max(0, h - PLANE_SHIFT_FROM) for h in range(options.levels)], np.int64)
        unit = 2 ** int(shift.max())
        # padded so that every plane's size divides evenly
        height, width = (-(-(n + 2 * p) // unit) * unit for n in occupied.shape)
        base = np.zeros((height, width), np.uint8)
        base[p:p + occupied.shape[0], p:p + occupied.shape[1]] = np.rint(self.field * 255).astype(np.uint8)
        # Level h reads widenings from margin(h, ~0) (1 cell of rounding for h > 0) up to
        # margin(h): only those planes are kept.
        self.index: dict[tuple[int, int], int] = {}
        for h in range(options.levels):
            for m in MARGINS:
                if m >= self.margin(h, 1e-6):
                    self.index[h, m] = len(self.index)
                    if m >= self.margin(h):
                        break
        # per level: its kept widenings, ascending, and their planes' indices (grid_ids looks them up)
        self.level_margins = [np.array([m for (k, m) in self.index if k == h], np.int64) for h in range(options.levels)]
        self.level_grids = [np.array([i for (k, _), i in self.index.items() if k == h], np.int64)
                            for h in range(options.levels)]
        sizes = [(height >> int(shift[h])) * (width >> int(shift[h])) for h, _ in self.index]
        self.offsets = np.cumsum([0] + sizes[:-1]).astype(np.int64)
        flat = np.empty(sum(sizes), np.uint8)      # written plane by plane: no list to concatenate
        plane = np.empty_like(base)
        for (h, m), start, n in zip(self.index, self.offsets, sizes, strict=True):
            k = 2 ** int(shift[h])
            # dilate's window at (x, y) spans [x - anchor, x - anchor + size): the block and m
            # around it, and the k - 1 cells after it that the stored cell (x, y) also stands for
            size = 2 ** h + 2 * m + k - 1
            cv2.dilate(base, np.ones((size, size), np.uint8), dst=plane, anchor=(m, m))
            flat[start:start + n].reshape(height >> int(shift[h]), width >> int(shift[h]))[:] = plane[::k, ::k]
        del plane, base
        self.planes = Planes(flat, shift, np.array([width >> int(s) for s in shift], np.int64), p, width, height)
        self.free = free_blocks(occupancy_map.free, options.levels)
        self.nbytes = self.field.nbytes + self.planes.flat.nbytes + self.free.flags.nbytes + self.occupied.nbytes

    def free_block(self, level: int, u, v):
        """Whether the level's blocks starting at map cells (u, v) hold a free cell."""
        f = self.free
        return f.flags[f.offsets[level] + (np.asarray(v) >> level) * f.width[level] + (np.asarray(u) >> level)] > 0

    @staticmethod
    def margin(level: int, range_fraction=1.0):
        """Cells by which a point at range_fraction x r_max may land from where it lands at
        the middle of a level-`level` node's 2^level angles: it moves at most d = (2^level
        - 1) / 2 x range_fraction cells (a chord at r_max spans one cell per angle step),
        and two values d apart round to cells at most ceil(d) apart (d + 1 only at exact
        ties, which the 1e-3 covers). range_fraction may be an array (one per point)."""
        if level == 0:
            return np.zeros_like(range_fraction, dtype=int)
        return np.ceil((2 ** level - 1) / 2.0 * np.asarray(range_fraction) + 1e-3).astype(int)

    def grid_ids(self, ranges: np.ndarray, r_max: float) -> np.ndarray:
        """(levels, points): the grid each point reads at each level, the one widened
        just enough for the point's range."""
        out = np.full((self.options.levels, len(ranges)), self.index[0, 0], np.int64)
        for h in range(1, self.options.levels):
            out[h] = self.level_grids[h][np.searchsorted(self.level_margins[h], self.margin(h, ranges / r_max))]
        return out


def free_blocks(free: np.ndarray, levels: int) -> FreeBlocks:
    """Per level h, whether block (u >> h, v >> h) of the map holds a free cell."""
    offsets, widths, blocks = [], [], []
    for h in range(levels):
        k = 2 ** h
        rows, cols = -(-free.shape[0] // k), -(-free.shape[1] // k)
        padded = np.zeros((rows * k, cols * k), bool)
        padded[:free.shape[0], :free.shape[1]] = free
        offsets.append(sum(len(b) for b in blocks))
        widths.append(cols)
        blocks.append(padded.reshape(rows, k, cols, k).any(axis=(1, 3)).astype(np.uint8).ravel())
    return FreeBlocks(np.concatenate(blocks), np.array(offsets, np.int64), np.array(widths, np.int64))
