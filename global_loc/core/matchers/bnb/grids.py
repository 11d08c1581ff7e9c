"""Per map, built once: the likelihood field and the max-pooled planes the search's
bounds read, and which blocks of the map hold a free cell (Cartographer's
PrecomputationGridStack2D). The search only reads them."""
from __future__ import annotations

from typing import Optional

import cv2
import numpy as np

from ...map_io import OccupancyMap
from .kernels import FreeBlocks, Planes
from .options import BranchAndBoundOptions

MARGINS = (0, 1, 2, 3, 4, 6, 8, 12, 16, 24, 32)   # widenings (cells) for which grids are kept
PLANE_SHIFT_FROM = 3                   # planes of level h > this are stored at 1 / 2^(h - this)
                                       # resolution (see PrecomputationGridStack), unless they
                                       # would exceed options.plane_memory_mb: then from a lower level


class PrecomputationGridStack:
    """Per map, built once: the likelihood field (uint8, `field`: what the map explains);
    the optimistic field (`optimistic`: unknown cells a beam can reach may hide a wall, so a
    point there, or near one, may be explained - OccupancyMap.open_unknown; the same as
    `field` on a map with none); per level and widening a uint8 plane whose cell holds the
    optimistic field's maximum over the block starting there and the widening around it
    (`grid_ids` picks one per point), and where the map has such unknown cells the same
    planes of the evidence field, so that a bound never rules out a place for what the map
    does not say (kernels: the two scores); per level, whether each block holds a free
    cell. Memory: `nbytes`.

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
        # Built in the order that keeps the peak low: the planes, the largest part, last, and
        # every array written where it is kept (36 Mcells: peak 1038 -> 881 MB, see fill_planes).
        open_unknown = occupancy_map.open_unknown() if options.unknown_credit > 0 else None
        has_unknown = open_unknown is not None and bool(open_unknown.any())
        field = likelihood_field(occupancy_map, options.sigma_cells, also=open_unknown if has_unknown else None)
        del open_unknown
        self.occupied = occupancy_map.occupied.view(np.uint8)     # 0 / 1 for the free-space check, no copy
        self.occupancy = occupancy_map.occupancy    # the map's own cells (no copy): which are unknown (free_space)
        self.free = free_blocks(occupancy_map.free, options.levels)
        p = (2 ** top) + 2 * int(self.margin(top)) + 2
        self.index_planes(options.levels)
        # The finest storage whose planes fit options.plane_memory_mb (coarser from a lower
        # level: looser bounds, more nodes; the leaves' level 0 is always whole).
        # (best effort: below shift_from 1 nothing is coarser - the budget may be exceeded)
        sets = 2 if has_unknown else 1      # the optimistic planes and their evidence twins
        for shift_from in range(PLANE_SHIFT_FROM, 0, -1):
            shift, height, width, sizes = self.plane_layout(field.shape, p, shift_from)
            if sets * sum(sizes) <= options.plane_memory_mb * 1e6:
                break
        self.shift_from = shift_from
        self.offsets = np.cumsum([0] + sizes[:-1]).astype(np.int64)
        # Where the map has unknown cells a beam can reach, the evidence field's planes (unknown
        # counts for nothing) follow the optimistic ones, laid out alike (kernels.Planes);
        # without any, one set is both (evidence offset 0).
        evidence = sum(sizes) if has_unknown else 0
        flat = np.empty(sets * sum(sizes), np.uint8)
        layout = [(h, m, int(shift[h]), int(o)) for (h, m), o in zip(self.index, self.offsets, strict=True)]
        fill_planes(flat, field, p, (height, width), layout)
        shape = field.shape
        del field
        if has_unknown:
            fill_planes(flat[evidence:], likelihood_field(occupancy_map, options.sigma_cells), p, (height, width),
                        layout)
        # The refinement reads the fields as the leaves' planes store them, rint(255 x
        # likelihood) (refine.FIELD_UNIT), through views without their frame: the float
        # fields (4 bytes a cell, 144 MB on 36 Mcells) are not kept, and a refined pose
        # scores what its leaf did
        self.optimistic = flat[:height * width].reshape(height, width)[p:p + shape[0], p:p + shape[1]]
        self.field = flat[evidence:evidence + height * width].reshape(height, width)[p:p + shape[0], p:p + shape[1]]
        self.planes = Planes(flat, shift, np.array([width >> int(s) for s in shift], np.int64), p, width, height,
                             evidence)
        # the evidence planes alone (the search for the best place: kernels.Planes with one set)
        self.evidence_planes = self.planes._replace(flat=flat[evidence:], evidence=0) if has_unknown else self.planes
        self.has_unknown = has_unknown
        self.nbytes = self.planes.flat.nbytes + self.free.flags.nbytes + self.occupied.nbytes

    def index_planes(self, levels: int) -> None:
        """Which planes are kept: level h reads widenings from margin(h, ~0) (1 cell of
        rounding for h > 0) up to margin(h), only those."""
        self.index: dict[tuple[int, int], int] = {}
        for h in range(levels):
            for m in MARGINS:
                if m >= self.margin(h, 1e-6):
                    self.index[h, m] = len(self.index)
                    if m >= self.margin(h):
                        break
        # per level: its kept widenings, ascending, and their planes' indices (grid_ids looks them up)
        self.level_margins = [np.array([m for (k, m) in self.index if k == h], np.int64) for h in range(levels)]
        self.level_grids = [np.array([i for (k, _), i in self.index.items() if k == h], np.int64)
                            for h in range(levels)]

    def plane_layout(self, shape: tuple[int, int], p: int, shift_from: int):
        """Planes of levels above shift_from stored at 1 / 2^(h - shift_from) resolution, for
        the planes of self.index and self.options.levels:
        (each level's shift, the padded map's height and width - padded so that every
        plane's size divides evenly - and each plane's cells, in index order)."""
        shift = np.array([max(0, h - shift_from) for h in range(self.options.levels)], np.int64)
        unit = 2 ** int(shift.max())
        height, width = (-(-(n + 2 * p) // unit) * unit for n in shape)
        return shift, height, width, [(height >> int(shift[h])) * (width >> int(shift[h])) for h, _ in self.index]

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


def likelihood_field(occupancy_map: OccupancyMap, sigma_cells: float, also: Optional[np.ndarray] = None) -> np.ndarray:
    """float32 (H, W): exp(-d^2 / 2 sigma^2) of each cell's distance d to the nearest
    occupied cell (or cell of `also`: unknown cells a beam can reach, where the most the map
    allows is a wall), computed in place (no float temporaries of the map's size)."""
    field = occupancy_map.distance_to_occupied(also).astype(np.float32, copy=False)
    np.square(field, out=field)
    field *= np.float32(-1.0 / (2.0 * sigma_cells ** 2))
    np.exp(field, out=field)
    return field


ROWS_PER_PASS = 1024       # rows dilated per pass for the shifted planes (plus the window's overlap)


def fill_planes(flat: np.ndarray, field: np.ndarray, p: int, shape: tuple[int, int], planes) -> None:
    """Write the planes into `flat`; `planes` lists (level h, widening m, shift, offset) in
    flat's order, the first (0, 0, 0, 0): rint(field x 255) framed by p zero cells to
    `shape`, which the others dilate. Plane (h, m) stored at 1 / k = 1 / 2^shift
    resolution holds at (Y, X) the maximum of the first over rows and columns [kY - m, kY
    - m + size) x [kX - m, kX - m + size), size = 2^h + 2m + k - 1 (the block and m around
    it, and the k - 1 cells after it that the stored cell also stands for). Every plane is
    written in place, the shifted ones first, dilated ROWS_PER_PASS rows at a time: no
    temporary of the map's size, and none left when the last full-size plane is written."""
    if tuple(planes[0]) != (0, 0, 0, 0):
        raise ValueError('the first plane must be the unwidened level 0')
    height, width = shape
    base = flat[:height * width].reshape(height, width)
    base[:p] = 0
    base[p + field.shape[0]:] = 0
    base[:, :p] = 0
    base[:, p + field.shape[1]:] = 0
    scaled = np.empty((min(256, field.shape[0]), field.shape[1]), np.float32)
    for r in range(0, field.shape[0], len(scaled)):      # np.rint(field * 255).astype(np.uint8), by rows
        rows = field[r:r + len(scaled)]
        np.multiply(rows, np.float32(255), out=scaled[:len(rows)])
        np.rint(scaled[:len(rows)], out=scaled[:len(rows)])
        base[p + r:p + r + len(rows), p:p + field.shape[1]] = scaled[:len(rows)]
    del scaled
    widened = [(m, 2 ** h + 2 * m + (1 << shift) - 1, shift,
                flat[offset:offset + (height >> shift) * (width >> shift)].reshape(height >> shift, width >> shift))
               for h, m, shift, offset in planes[1:]]
    shifted = [w for w in widened if w[2] > 0]
    if shifted:
        dilated = np.empty((min(height, ROWS_PER_PASS + max(w[1] for w in shifted)), width), np.uint8)
        for m, size, shift, out in shifted:
            dilate_shifted(base, m, size, 1 << shift, out, dilated)
        del dilated
    for m, size, _, out in (w for w in widened if w[2] == 0):
        cv2.dilate(base, np.ones((size, size), np.uint8), dst=out, anchor=(m, m))


def dilate_shifted(base: np.ndarray, m: int, size: int, k: int, out: np.ndarray, dilated: np.ndarray) -> None:
    """out[Y, X] = cv2.dilate(base, size x size, anchor (m, m))[kY, kX], computed
    ROWS_PER_PASS rows of base at a time in `dilated` (at least ROWS_PER_PASS + size rows)."""
    kernel = np.ones((size, size), np.uint8)
    step = max(1, ROWS_PER_PASS // k)      # stored rows per pass (a stored row stands for k rows of base)
    for y0 in range(0, out.shape[0], step):
        y1 = min(out.shape[0], y0 + step)
        # the rows of base that stored rows y0 .. y1 - 1 read; rows past its edge count as 0
        a, b = max(0, k * y0 - m), min(base.shape[0], k * (y1 - 1) - m + size)
        cv2.dilate(base[a:b], kernel, dst=dilated[:b - a], anchor=(m, m))
        out[y0:y1] = dilated[k * y0 - a:k * (y1 - 1) - a + 1:k, ::k]


def free_blocks(free: np.ndarray, levels: int) -> FreeBlocks:
    """Per level h, whether block (u >> h, v >> h) of the map holds a free cell: level 0 is
    `free`, level h the 2 x 2 blocks of level h - 1 (blocks past the map's edge hold none)."""
    shapes = [(-(-free.shape[0] // 2 ** h), -(-free.shape[1] // 2 ** h)) for h in range(levels)]
    offsets = np.cumsum([0] + [r * c for r, c in shapes[:-1]]).astype(np.int64)
    flags = np.empty(sum(r * c for r, c in shapes), np.uint8)
    level = flags[:free.size].reshape(free.shape)
    level[:] = free
    for (rows, cols), offset in zip(shapes[1:], offsets[1:], strict=True):
        below, level = level, flags[offset:offset + rows * cols].reshape(rows, cols)
        r, c = below.shape[0] // 2, below.shape[1] // 2       # the blocks with a second row, column below
        level[:] = below[0::2, 0::2]
        np.maximum(level[:r], below[1::2, 0::2], out=level[:r])
        np.maximum(level[:, :c], below[0::2, 1::2], out=level[:, :c])
        np.maximum(level[:r, :c], below[1::2, 1::2], out=level[:r, :c])
    return FreeBlocks(flags, offsets, np.array([c for _, c in shapes], np.int64))
