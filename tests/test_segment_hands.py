"""Fingers on an object and blobs apart from it are not the object: the depth segmenter's skin
peel and its main-part filter, on masks whose answer is drawn by hand."""

from __future__ import annotations

import numpy as np

from rose_usd.segment.colors import color_index, histogram
from rose_usd.segment.regions import main_part, peel_skin

W, H = 120, 90
SKIN = (224, 168, 140)
WHITE = (240, 238, 232)
BROWN = (90, 55, 30)


def _object_image():
    """A 40 x 40 object of white and brown 3-px stripes (rows 20-60, cols 30-70) on a grey table."""
    rgb = np.full((H, W, 3), 128, np.uint8)
    obj = np.zeros((H, W), bool)
    obj[20:60, 30:70] = True
    stripes = (np.arange(W)[None, :] // 3) % 2 == 0
    rgb[obj & stripes] = WHITE
    rgb[obj & ~stripes] = BROWN
    return rgb, obj


def test_a_finger_on_the_object_is_peeled_and_the_object_stays():
    """A skin-coloured finger inside the object's mask that runs on into the hand outside it is
    taken off; the object's own pixels stay, and so does a skin-coloured patch at its other side
    that touches only the table."""
    rgb, obj = _object_image()
    color = histogram(color_index(rgb)[obj])
    finger = np.zeros_like(obj)
    finger[35:42, 58:70] = True  # on the object's right edge
    patch = np.zeros_like(obj)
    patch[30:36, 30:36] = True  # on its left edge, nothing in front of the table there
    hand = np.zeros_like(obj)
    hand[30:48, 70:95] = True  # the hand the finger belongs to, outside the object
    rgb[finger | patch | hand] = SKIN
    skin = histogram(color_index(rgb)[hand])
    peeled = peel_skin(obj | finger, color_index(rgb), color, skin, hand, 2.0)
    assert peeled[finger].mean() < 0.2, peeled[finger].mean()
    assert peeled[obj & ~finger & ~patch].mean() > 0.97
    assert peeled[patch].all()


def test_a_print_of_skin_like_colours_mixed_with_others_stays():
    """An object printed with skin-like and brown stripes (a paper cup's print) that touches the
    hand keeps its stripes: averaged over 2 px, its colours are the object's."""
    rgb, obj = _object_image()
    stripes = (np.arange(W)[None, :] // 2) % 2 == 0
    rgb[obj & stripes] = SKIN
    hand = np.zeros_like(obj)
    hand[30:48, 70:95] = True
    rgb[hand] = SKIN
    skin = histogram(color_index(rgb)[hand])
    color = histogram(color_index(rgb)[obj])
    peeled = peel_skin(obj, color_index(rgb), color, skin, hand, 2.0)
    assert peeled[obj].mean() > 0.97


def test_small_blobs_apart_from_the_object_are_dropped():
    """A blob far from the object's largest part is dropped, one a finger's width away (the object
    seen past a finger) is kept, and a mask in pieces (a held object between fingers) stays whole."""
    mask = np.zeros((H, W), bool)
    mask[20:60, 20:60] = True  # 1600 px
    far = np.zeros_like(mask)
    far[5:12, 100:110] = True
    beside = np.zeros_like(mask)
    beside[30:40, 63:68] = True  # 3 px past the main part's edge
    kept = main_part(mask | far | beside, area_px=1600.0)
    assert np.array_equal(kept, mask | beside)
    pieces = np.zeros_like(mask)
    for c in range(10, 110, 20):
        pieces[40:50, c : c + 8] = True  # 80 px each, < 1/4 of the start area
    assert np.array_equal(main_part(pieces, area_px=1600.0), pieces)


def test_what_is_off_the_object_surface_is_found():
    """A 10 cm box face 0.5 m in front of the camera, a 1.5 cm thick finger lying on it: the
    finger's pixels are off the face's surface (in front of it), and so are pixels beside the box
    (outside its silhouette), up to the image's edges; the face's own pixels (depth noise 3 mm)
    are on it."""
    from rose_usd.segment.regions import off_surface

    K = np.array([[100.0, 0, W / 2], [0, 100.0, H / 2], [0, 0, 1]])
    pose = np.eye(4)  # camera = world, looking along +z
    g = np.linspace(-0.05, 0.05, 60)
    face = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    points = np.column_stack([face, np.full(len(face), 0.5)])
    depth = np.zeros((H, W), np.float32)
    rows, cols = np.mgrid[0:H, 0:W]
    on_face = (np.abs(cols - W / 2) < 9) & (np.abs(rows - H / 2) < 9)
    depth[on_face] = 0.5 + 0.003 * np.random.default_rng(0).standard_normal(on_face.sum())
    finger = on_face & (np.abs(rows - H / 2) < 2)
    depth[finger] = 0.485
    beside = (np.abs(cols - W / 2) > 20) & (np.abs(cols - W / 2) < 30)
    depth[beside] = 0.3
    depth[:, :2] = depth[:, -2:] = 0.5  # the image's edges, far from the box
    ys, xs = np.nonzero(depth > 0)
    off = np.zeros((H, W), bool)
    off[ys, xs] = off_surface(points, pose, K, depth, ys, xs, 0.01)
    assert off[finger].all()
    assert not off[on_face & ~finger].any()
    assert off[beside].all() and off[:, :2].all() and off[:, -2:].all()
    # without ``outside`` (an arm followed, no hand found) only what is in front of the face is off
    off[ys, xs] = off_surface(points, pose, K, depth, ys, xs, 0.01, outside=False)
    assert off[finger].all()
    assert not off[on_face & ~finger].any() and not off[beside].any()


def test_sensor_holes_in_a_sleeve_are_bridged_and_nothing_else():
    """A sleeve in front of the table whose depth has holes every few pixels (dark cloth) is one
    region once bridged; a table pixel with depth between the sleeve and a blob 3 px away keeps its
    own answer (it is not foreground), so the blob is not joined through it; a hand with a few
    holes at its edge gets none added."""
    from rose_usd.segment.regions import bridge_holes, components

    depth = np.full((H, W), 0.8, np.float32)
    fg = np.zeros((H, W), bool)
    fg[40:60, 10:100] = True
    holes = np.zeros((H, W), bool)
    holes[40:60, 12:98:4] = True  # every 4th column inside the sleeve has no depth
    depth[holes] = 0.0
    fg &= ~holes
    assert components(fg)[0] - 1 > 1  # specks
    bridged = bridge_holes(fg, depth)
    assert components(bridged)[0] - 1 == 1 and bridged[holes].all()
    blob = np.zeros((H, W), bool)
    blob[40:60, 103:110] = True  # beyond the table pixels at columns 100-102, which have depth
    joined = bridge_holes(fg | blob, depth)
    assert not joined[40:60, 100:103].any()
    # a hand seen whole, with the sensor's shadow (no depth) in a notch of its outline: the
    # shadow is background seen past the hand, not bridged
    depth = np.full((H, W), 0.8, np.float32)
    hand = np.zeros((H, W), bool)
    hand[30:70, 20:80] = True
    hand[49:52, 76:80] = False
    depth[49:52, 76:80] = 0.0
    assert np.array_equal(bridge_holes(hand, depth), hand)


def test_an_object_back_from_hiding_is_taken_off_the_hand_beside_its_stale_points():
    """A tracked face (10 cm, 0.5 m away) hidden for 3 frames (under a cup) comes back in the hand
    1 cm beside where its last points are: its pixels lie on the arm, outside the silhouette
    those stale points show, within core_m of them. A track seen in the frame before is held to
    its silhouette (fingers around it are not it); a hidden one is not (the ball of cups-rgbd,
    taken out from under the cup, was never found again)."""
    from types import SimpleNamespace

    from rose_usd.segment.segmenter import Segmenter

    K = np.array([[200.0, 0, W / 2], [0, 200.0, H / 2], [0, 0, 1]])  # 2.5 mm a pixel at 0.5 m
    g = np.linspace(-0.05, 0.05, 60)
    face = np.stack(np.meshgrid(g, g), -1).reshape(-1, 2)
    points = np.column_stack([face, np.full(len(face), 0.5)])
    depth = np.full((H, W), 0.5, np.float32)
    xs = np.full(10, W // 2 + 24)  # x = 6 cm: 1 cm beside the face's edge, 2 px beyond its silhouette
    ys = np.arange(H // 2 - 5, H // 2 + 5)
    d = np.full(len(xs), 0.01)
    arm = np.ones((H, W), bool)
    seg = SimpleNamespace(
        cam=SimpleNamespace(world_from_cv=[np.eye(4)], K=[K]),
        frame=lambda t: SimpleNamespace(depth=depth),
        config=SimpleNamespace(occluder_m=0.01),
    )
    for hidden, taken in ((0, False), (3, True)):
        track = SimpleNamespace(hidden=hidden, motion_m=lambda: 0.0)
        ok = Segmenter._arm_allows(seg, 0, track, points, (ys, xs, d), 0.015, arm, True)
        assert ok.all() if taken else not ok.any(), (hidden, ok.mean())
