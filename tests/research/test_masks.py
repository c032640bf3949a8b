"""The masks' measures: the thin parts' recall of a photo's mask."""

import numpy as np

from model.data.photos import Photo
from research.masks import thin_recall


def rod_photo() -> Photo:
    """A 100 x 100 photo's exact mask: a body 80 x 50 with a rod two pixels thick."""
    m = np.zeros((100, 100), np.float32)
    m[10:90, 10:60] = 1
    m[40:42, 60:90] = 1
    return Photo(np.zeros((100, 100, 3), np.uint8), m, (10, 10, 90, 90))


def test_the_thin_parts_recall_is_the_share_of_the_exact_masks_thin_pixels_a_mask_keeps():
    photo = rod_photo()
    truth = photo.mask > 0.5
    assert thin_recall(truth, photo) == 1.0
    assert thin_recall(np.zeros_like(truth), photo) == 0.0
    body = truth.copy()
    body[:, 60:] = False                                  # the rod lost, the body kept
    # thin: within 2% of the box's longest side (80 px: 1.6 px) of the background; the rod is all thin,
    # the body's rim one pixel deep (its next ring is 2 px in); the rod's 60 pixels are lost of them all
    rim = np.zeros_like(truth)
    rim[10:90, 10:60] = True
    rim[11:89, 11:59] = False
    thin = rim | (truth & ~body)
    assert thin.sum() == rim.sum() + 60
    got = thin_recall(body, photo)
    assert abs(got - (thin & body).sum() / thin.sum()) < 1e-12 and got == 256 / 316
    assert thin_recall(body | ~truth, photo) == got          # background taken along changes nothing
