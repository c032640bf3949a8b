"""Procedural categories: validity, normalisation, determinism, variety, splits."""

import numpy as np
import pytest

from model.data.shapes import CATEGORIES, GENERATORS, SYNSETS, generate, split_of


def test_categories_and_synsets():
    assert len(CATEGORIES) == 13
    assert list(CATEGORIES) == sorted(CATEGORIES)
    assert set(SYNSETS) == set(CATEGORIES)
    assert SYNSETS["chair"] == "03001627" and SYNSETS["watercraft"] == "04530566"


@pytest.mark.parametrize("category", CATEGORIES)
def test_generated_meshes_are_valid_and_normalised(category):
    faces_counts = []
    for i in range(10):
        m = generate(category, i)
        v, f = m.vertices, m.faces
        assert np.isfinite(v).all()
        assert f.min() >= 0 and f.max() < len(v)
        assert len(f) >= 12
        area = m.area_faces
        assert (area > 1e-10).mean() > 0.95, "too many degenerate faces"
        lo, hi = v.min(axis=0), v.max(axis=0)
        assert np.isclose((hi - lo).max(), 1.0, atol=1e-9)
        np.testing.assert_allclose((lo + hi) / 2, 0.0, atol=1e-9)
        assert (hi - lo).min() > 0.01, "flat shape"
        faces_counts.append(len(f))
    # Part counts vary within a category.
    assert len(set(faces_counts)) >= 3


@pytest.mark.parametrize("category", CATEGORIES)
def test_generation_is_deterministic(category):
    a, b = generate(category, 3, seed=7), generate(category, 3, seed=7)
    np.testing.assert_array_equal(a.vertices, b.vertices)
    np.testing.assert_array_equal(a.faces, b.faces)
    c = generate(category, 4, seed=7)
    d = generate(category, 3, seed=8)
    for other in (c, d):
        assert other.vertices.shape != a.vertices.shape or not np.allclose(other.vertices, a.vertices)


def test_orientation_conventions():
    # Cars and rifles are long along Z (front axis), chairs and lamps... stand along Y.
    for i in range(5):
        assert np.argmax(generate("car", i).extents) == 2
        assert np.argmax(generate("rifle", i).extents) == 2
        e = generate("car", i).extents
        assert e[1] < e[2]
    # Car wheels touch the ground: the lowest points are at the bottom of the box.
    assert np.isclose(generate("car", 0).vertices[:, 1].min(), -generate("car", 0).extents[1] / 2)


def _loo_1nn_accuracy(features, labels):
    d = np.linalg.norm(features[:, None] - features[None], axis=2)
    np.fill_diagonal(d, np.inf)
    return float((labels[d.argmin(axis=1)] == labels).mean())


def test_categories_not_separable_by_bbox():
    ext, lab = [], []
    for c in CATEGORIES:
        for i in range(16):
            ext.append(generate(c, i).extents)
            lab.append(c)
    ext, lab = np.array(ext), np.array(lab)
    # Chance is 1/13; rotation-invariant box size must stay a weak cue, axis-aligned
    # box proportions a partial one (as for real ShapeNet shapes).
    assert _loo_1nn_accuracy(np.sort(ext, axis=1), lab) < 0.6
    assert _loo_1nn_accuracy(ext, lab) < 0.8
    # Each category's range of the height/length ratio overlaps another category's.
    ratio = ext[:, 1] / ext.max(axis=1)
    ranges = {c: (ratio[lab == c].min(), ratio[lab == c].max()) for c in CATEGORIES}
    for c, (lo, hi) in ranges.items():
        assert any(lo2 <= hi and lo <= hi2 for c2, (lo2, hi2) in ranges.items() if c2 != c), c


def test_split_is_deterministic_and_balanced():
    splits = [split_of("chair", i) for i in range(2000)]
    assert splits == [split_of("chair", i) for i in range(2000)]
    frac = {s: splits.count(s) / len(splits) for s in ("train", "val", "test")}
    assert abs(frac["train"] - 0.8) < 0.04 and abs(frac["val"] - 0.1) < 0.03 and abs(frac["test"] - 0.1) < 0.03


def test_unknown_category_lists_valid_ones():
    with pytest.raises(ValueError, match="airplane.*watercraft"):
        generate("spaceship", 0)
    with pytest.raises(ValueError, match="valid categories"):
        split_of("spaceship", 0)


def _same(a, b) -> bool:
    return a.vertices.shape == b.vertices.shape and np.array_equal(a.vertices, b.vertices) \
        and np.array_equal(a.faces, b.faces)


def test_the_second_generator_changes_chairs_only():
    assert sorted(GENERATORS) == [1, 2]
    for category in CATEGORIES:
        if category != "chair":
            assert all(_same(generate(category, i, 5, 2), generate(category, i, 5, 1)) for i in range(3))
    v1 = [generate("chair", i, 5, 1) for i in range(20)]
    v2 = [generate("chair", i, 5, 2) for i in range(20)]
    assert not any(_same(a, b) for a, b in zip(v1, v2))
    assert all(_same(generate("chair", i, 5), a) for i, a in enumerate(v1[:3]))  # version 1 by default
    with pytest.raises(ValueError, match="unknown generator 3"):
        generate("chair", 0, 0, 3)


@pytest.mark.parametrize("kind", ["folding", "panel", "cantilever", "club"])
def test_the_new_chair_kinds_stand_upright_and_vary(kind):
    from model.data.shapes.furniture import _CHAIR_KINDS

    sizes = []
    for i in range(8):
        m = _CHAIR_KINDS[kind](np.random.default_rng(i)).mesh()
        lo, hi = m.vertices.min(0), m.vertices.max(0)
        assert np.isclose((hi - lo).max(), 1.0) and (hi - lo).min() > 0.3   # a chair, not a plate or a stick
        assert (m.area_faces > 1e-10).mean() > 0.95
        assert m.bounds[1][1] - m.bounds[0][1] > 0.55                     # standing: at least half as tall as wide
        sizes.append(len(m.faces))
        sizes.append(tuple(np.round(hi - lo, 3)))
    assert len(set(sizes)) >= 8


def test_the_new_kinds_are_drawn_at_their_shares(monkeypatch):
    from model.data.shapes import furniture

    made = []
    monkeypatch.setattr(furniture, "_CHAIR_KINDS", {k: (lambda rng, k=k: made.append(k) or furniture.Assembly())
                                                    for k in furniture.CHAIR_KINDS})
    for i in range(2000):
        furniture.chair_wider(np.random.default_rng(i))
    for kind, share in furniture.CHAIR_KINDS.items():
        assert abs(made.count(kind) / 2000 - share) < 0.025, kind
    assert abs(len(made) / 2000 - sum(furniture.CHAIR_KINDS.values())) < 0.03
