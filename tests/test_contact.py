"""First contact between the interactor's and an object's masks, on hand-made masks and depth."""

import numpy as np

from rose_usd.geometry.contact import first_contact


def _scene(n: int = 6):
    depth = np.full((60, 80), 0.8, np.float32)
    obj = np.zeros((60, 80), bool)
    obj[20:40, 30:50] = True  # 400 px
    return depth, [obj.copy() for _ in range(n)]


def test_a_sliver_at_the_rim_is_not_a_touch_but_a_hand_is():
    depth, masks = _scene()
    hands = []
    for t in range(6):
        hand = np.zeros_like(masks[0])
        if t < 3:
            hand[20:40, 50:52] = True  # 40 px right at the object's rim: a sliver of its own depth
        else:
            hand[15:45, 50:60] = True  # 300 px: a hand against its side
        hands.append(hand)
    assert first_contact(masks, lambda t: hands[t], lambda t: depth, 6) == 3


def test_no_interactor_means_no_contact():
    depth, masks = _scene()
    assert first_contact(masks, lambda t: None, lambda t: depth, 6) == 6
