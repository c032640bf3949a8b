"""The compiled walks over the grid's corners give SciPy's arrays, bit for bit, on random grids."""

import numpy as np
import pytest
from scipy import ndimage

from model.surface import flood
from model.surface.tables import REPAIR

SIX = ndimage.generate_binary_structure(3, 1)


def grids(count: int, seed: int):
    rng = np.random.default_rng(seed)
    for _ in range(count):
        shape = tuple(int(s) for s in rng.integers(3, 20, 3))
        yield rng, rng.random(shape) < rng.uniform(0.3, 0.8)


def test_reached_is_the_labelled_parts_that_touch_the_border():
    for _, free in grids(25, 0):
        labels, _ = ndimage.label(free, SIX)
        border = np.unique(np.concatenate([labels[[0, -1]].ravel(), labels[:, [0, -1]].ravel(),
                                           labels[:, :, [0, -1]].ravel()]))
        assert np.array_equal(flood.reached(free), np.isin(labels, border[border > 0]))


@pytest.mark.parametrize("steps", [1, 2, 4])
def test_erosion_and_dilation_are_scipys_iterated_cross(steps):
    for rng, mask in grids(15, steps):
        assert np.array_equal(flood.eroded(mask, steps),
                              ndimage.binary_erosion(mask, SIX, iterations=steps, border_value=1))
        seed = mask & (rng.random(mask.shape) < 0.05)
        assert np.array_equal(flood.dilated(seed, mask, steps),
                              ndimage.binary_dilation(seed, SIX, iterations=steps, mask=mask))


OFFSETS = np.array([[c & 1, c >> 1 & 1, c >> 2 & 1] for c in range(8)])


def _configurations(inside: np.ndarray) -> np.ndarray:
    config = np.zeros(tuple(s - 1 for s in inside.shape), np.uint8)
    for c, (x, y, z) in enumerate(OFFSETS):
        config |= inside[x:x + config.shape[0], y:y + config.shape[1], z:z + config.shape[2]].astype(np.uint8) << c
    return config


def _repaired_pass_by_pass(inside: np.ndarray, max_rounds: int = 64) -> tuple[np.ndarray, int]:
    """The reference: every round judges every cell (NumPy), enclosed regions filled by labelling."""
    inside = inside.copy()
    turned = 0
    for _ in range(max_rounds):
        fix = REPAIR[_configurations(inside)]
        cells = np.argwhere(fix >= 0)
        corner = cells + OFFSETS[fix[cells[:, 0], cells[:, 1], cells[:, 2]]]
        corner = corner[np.all((corner > 0) & (corner < np.array(inside.shape) - 1), axis=1)]
        if not len(corner):
            labels, _ = ndimage.label(~inside, SIX)
            border = np.unique(np.concatenate([labels[[0, -1]].ravel(), labels[:, [0, -1]].ravel(),
                                               labels[:, :, [0, -1]].ravel()]))
            filled = inside | ~np.isin(labels, border[border > 0])
            if np.array_equal(filled, inside):
                return inside, turned
            inside = filled
            continue
        inside[corner[:, 0], corner[:, 1], corner[:, 2]] = True
        turned += len(np.unique(corner, axis=0))
    return inside, turned


def test_the_repair_re_judging_only_cells_around_turned_corners_ends_where_every_cell_is_judged():
    repairs = 0
    for _, inside in grids(25, 7):
        inside[[0, -1]] = inside[:, [0, -1]] = inside[:, :, [0, -1]] = False      # the grid's border is outside
        got, turned, _ = flood.repaired(inside, REPAIR, 64)
        want, want_turned = _repaired_pass_by_pass(inside)
        assert np.array_equal(got, want) and turned == want_turned
        repairs += turned
        assert np.array_equal(flood.configurations(got), _configurations(got))
        assert not (REPAIR[flood.configurations(got)[1:-1, 1:-1, 1:-1]] >= 0).any()   # inner cells need none
    assert repairs > 50                                    # the grids needed repairs: the test tests them
