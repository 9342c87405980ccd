"""Point labels of the tradeoff plot: placed where they print over nothing."""

import itertools

from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.text import Annotation, Text

from lenspair.model.evaluation.plot_labels import (
    ABOVE,
    BELOW,
    CANDIDATES,
    Box,
    choose_candidates,
    label_box,
    label_points,
)

FRAME = Box(0, 0, 1000, 600)
SIZE = (60.0, 10.0)


def _boxes(anchors: list[tuple[float, float]], chosen: list[int]) -> list[Box]:
    return [label_box(a, SIZE, CANDIDATES[c], 1.0) for a, c in zip(anchors, chosen, strict=True)]


def test_isolated_points_keep_their_first_choice() -> None:
    anchors = [(100.0, 100.0), (500.0, 300.0), (800.0, 100.0)]
    chosen = choose_candidates(anchors, [SIZE] * 3, [], FRAME, [ABOVE, BELOW, ABOVE], 1.0)
    assert chosen == [ABOVE, BELOW, ABOVE]


def test_labels_of_one_spot_go_different_ways_and_do_not_overlap() -> None:
    # four networks of one speed and accuracy: at one fixed offset, one label over another
    anchors = [(500.0, 300.0)] * 4
    chosen = choose_candidates(anchors, [SIZE] * 4, [], FRAME, [ABOVE] * 4, 1.0)
    assert len(set(chosen)) == 4
    for first, second in itertools.combinations(_boxes(anchors, chosen), 2):
        assert first.overlap(second) == 0


def test_a_label_at_the_frame_edge_turns_inwards() -> None:
    anchors = [(995.0, 595.0)]  # top-right corner: above-right would be clipped
    (chosen,) = choose_candidates(anchors, [SIZE], [], FRAME, [ABOVE], 1.0)
    box = label_box(anchors[0], SIZE, CANDIDATES[chosen], 1.0)
    assert box.outside(FRAME) == 0 and box.x1 <= anchors[0][0]


def test_markers_and_the_legend_are_not_covered() -> None:
    anchor = (500.0, 300.0)
    legend = label_box(anchor, SIZE, CANDIDATES[ABOVE], 1.0)  # exactly where it would go
    marker = Box(495, 280, 505, 295)  # a point right below
    (chosen,) = choose_candidates([anchor], [SIZE], [legend, marker], FRAME, [ABOVE], 1.0)
    box = label_box(anchor, SIZE, CANDIDATES[chosen], 1.0)
    assert box.overlap(legend) == 0 and box.overlap(marker) == 0
    assert not CANDIDATES[chosen].far  # a near position was free


def test_drawn_labels_of_a_dense_cluster_do_not_overlap() -> None:
    # the real text extents, as matplotlib draws them: what the pure geometry assumed
    figure = Figure(figsize=(5.5, 4.5), dpi=110)  # one panel of the tradeoff plot
    canvas = FigureCanvasAgg(figure)
    axes = figure.add_subplot(1, 1, 1)
    points = [(100.0, 0.8729), (104.0, 0.8729), (108.0, 0.87291), (103.0, 0.87283),
              (190.0, 0.8727), (200.0, 0.8727), (400.0, 0.8717), (660.0, 0.8717)]  # fmt: skip
    axes.scatter(*zip(*points, strict=True))
    axes.legend(["points"], loc="best")
    names = [f"{name} {precision}" for name in ("G", "GEA-w0.5") for precision in ("fp32", "bf16")]
    names += ["GEA int8", "GEA bf16", "GEA-w2 fp32", "GEA-w2 bf16"]
    figure.tight_layout()
    canvas.draw()
    label_points(axes, points, names, [ABOVE] * len(points), canvas.get_renderer())
    canvas.draw()
    renderer = canvas.get_renderer()
    labels = [t for t in axes.texts if isinstance(t, Annotation)]
    assert sorted(t.get_text() for t in labels) == sorted(names)
    # the texts alone: an annotation's own extent includes its leader line
    extents = [Text.get_window_extent(t, renderer) for t in labels]
    inside = axes.get_window_extent(renderer)
    legend = axes.get_legend().get_window_extent(renderer)
    for extent in extents:
        assert extent.width > 20  # measured, not a unit box
        assert inside.x0 <= extent.x0 and extent.x1 <= inside.x1
        assert inside.y0 <= extent.y0 and extent.y1 <= inside.y1
        assert not extent.overlaps(legend)
    for first, second in itertools.combinations(extents, 2):
        assert not first.overlaps(second)
