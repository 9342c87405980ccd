"""Point labels on a scatter plot that print over neither each other nor the points.

The tradeoff plot names every point (``GEA bf16``), and networks of similar
speed and accuracy sit close together: labels at one fixed offset printed
over each other. :func:`label_points` places them greedily instead, the most
constrained label first (:func:`choose_candidates`). Each takes, among the
candidate positions (:data:`CANDIDATES`: beside its point in eight
directions, then the same three and five times farther out, with a leader
line), the one whose box overlaps the least area of the boxes already taken
(labels placed before it, every point's marker, the legend) and sticks out of
the axes the least. The geometry works in display pixels and is pure, so it
is tested without drawing; only :func:`label_points` touches matplotlib.
"""

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

from matplotlib.axes import Axes
from matplotlib.backend_bases import RendererBase

HorizontalAlignment = Literal["left", "center", "right"]
VerticalAlignment = Literal["bottom", "center", "top"]


@dataclass(frozen=True)
class Box:
    """An axis-aligned box in display pixels (``x0 <= x1``, ``y0 <= y1``)."""

    x0: float
    y0: float
    x1: float
    y1: float

    def overlap(self, other: "Box") -> float:
        """The area this box shares with ``other`` (0 when they only touch)."""
        width = min(self.x1, other.x1) - max(self.x0, other.x0)
        height = min(self.y1, other.y1) - max(self.y0, other.y0)
        return max(width, 0.0) * max(height, 0.0)

    def outside(self, frame: "Box") -> float:
        """The area of this box that lies outside ``frame``."""
        area = (self.x1 - self.x0) * (self.y1 - self.y0)
        return area - self.overlap(frame)


@dataclass(frozen=True)
class Candidate:
    """A label position: offset from its point (points, 1/72 inch) and the text's alignment."""

    dx: float
    dy: float
    ha: HorizontalAlignment
    va: VerticalAlignment

    @property
    def far(self) -> bool:
        """Whether the label sits far enough from its point to need a leader line."""
        return max(abs(self.dx), abs(self.dy)) > NEAR


NEAR = 8.0
"""Largest offset (points) of the positions right beside a point."""


def _ring(distance: float) -> tuple[Candidate, ...]:
    d = distance
    return (
        Candidate(d / 2, d / 2, "left", "bottom"),
        Candidate(d / 2, -d / 2, "left", "top"),
        Candidate(-d / 2, d / 2, "right", "bottom"),
        Candidate(-d / 2, -d / 2, "right", "top"),
        Candidate(0, d, "center", "bottom"),
        Candidate(0, -d, "center", "top"),
        Candidate(d, 0, "left", "center"),
        Candidate(-d, 0, "right", "center"),
    )


CANDIDATES: tuple[Candidate, ...] = _ring(NEAR) + _ring(3 * NEAR) + _ring(5 * NEAR)
"""Where a label may go, in order of preference for ties (above-right first)."""

ABOVE, BELOW = 0, 1
"""Indices in :data:`CANDIDATES` of the above-right and below-right positions."""


def label_box(anchor: tuple[float, float], size: tuple[float, float], offset: Candidate,
              pixels_per_point: float) -> Box:  # fmt: skip
    """The display box of a ``size`` (pixels) label at ``offset`` from ``anchor`` (pixels)."""
    x = anchor[0] + offset.dx * pixels_per_point
    y = anchor[1] + offset.dy * pixels_per_point
    width, height = size
    x0 = {"left": x, "center": x - width / 2, "right": x - width}[offset.ha]
    y0 = {"bottom": y, "center": y - height / 2, "top": y - height}[offset.va]
    return Box(x0, y0, x0 + width, y0 + height)


def choose_candidates(
    anchors: Sequence[tuple[float, float]],
    sizes: Sequence[tuple[float, float]],
    obstacles: Sequence[Box],
    frame: Box,
    first_choice: Sequence[int],
    pixels_per_point: float,
) -> list[int]:
    """For each label, the index in :data:`CANDIDATES` of its position.

    Labels are placed one at a time, most constrained first: the next is
    the one with the fewest free positions left (ties: the earlier label),
    and it takes its position of least clash (ties: its first choice, then a
    near position before a far one). A label's clash is the area it shares
    with the obstacles and the labels placed before it, plus its area outside
    ``frame``.

    Args:
        anchors: each label's point, display pixels.
        sizes: each label's width and height, pixels.
        obstacles: boxes no label should cover (the markers, the legend).
        frame: the axes; a label outside it would be clipped.
        first_choice: each label's preferred index.
        pixels_per_point: display pixels per typographic point (dpi / 72).

    Returns:
        One index per label, in the order given.
    """
    taken = list(obstacles)
    chosen: dict[int, int] = {}

    def clash(label: int, index: int) -> float:
        box = label_box(anchors[label], sizes[label], CANDIDATES[index], pixels_per_point)
        return sum(box.overlap(other) for other in taken) + box.outside(frame)

    def preference(label: int) -> list[int]:
        first = first_choice[label]
        return [first, *(i for i in range(len(CANDIDATES)) if i != first)]

    while len(chosen) < len(anchors):
        free = {
            label: sum(clash(label, index) == 0 for index in range(len(CANDIDATES)))
            for label in range(len(anchors))
            if label not in chosen
        }
        label = min(free, key=lambda lab: (free[lab], lab))
        # min keeps the first of equal keys: the first choice, then near before far
        best = min(preference(label), key=lambda i: (clash(label, i), CANDIDATES[i].far))
        chosen[label] = best
        taken.append(label_box(anchors[label], sizes[label], CANDIDATES[best], pixels_per_point))
    return [chosen[label] for label in range(len(anchors))]


def label_points(
    axes: Axes,
    points: Sequence[tuple[float, float]],
    texts: Sequence[str],
    first_choice: Sequence[int],
    renderer: RendererBase,
    fontsize: float = 7,
    marker_radius: float = 4.0,
) -> None:
    """Annotate ``points`` (data coordinates) with ``texts`` where they clash least.

    Call it once the axes' limits and the legend are final (after
    ``tight_layout`` and a draw): positions are worked out in display pixels.
    A legend whose location is ``"best"`` is pinned where that draw put it, so
    that it does not move onto the labels.

    Args:
        axes: the axes holding the points.
        points: ``(x, y)`` per label, data coordinates.
        texts: the labels.
        first_choice: each label's preferred index in :data:`CANDIDATES`
            (:data:`ABOVE`, :data:`BELOW`).
        renderer: the figure canvas's renderer (measures the text).
        fontsize: the labels' size, points.
        marker_radius: half the side of the box kept free around each point, points.
    """
    pixels_per_point = axes.figure.dpi / 72.0
    anchors = [tuple(axes.transData.transform(p)) for p in points]
    sizes = []
    for text in texts:
        # a plain text: an annotation whose point lies outside the axes measures 1x1
        probe = axes.text(0.5, 0.5, text, fontsize=fontsize, transform=axes.transAxes)
        extent = probe.get_window_extent(renderer)
        sizes.append((extent.width, extent.height))
        probe.remove()
    half = marker_radius * pixels_per_point
    obstacles = [Box(x - half, y - half, x + half, y + half) for x, y in anchors]
    legend = axes.get_legend()
    if legend is not None:
        extent = legend.get_window_extent(renderer)
        obstacles.append(Box(extent.x0, extent.y0, extent.x1, extent.y1))
        corner = axes.transAxes.inverted().transform((extent.x0, extent.y0))
        legend.set_loc((float(corner[0]), float(corner[1])))
    window = axes.get_window_extent(renderer)
    frame = Box(window.x0, window.y0, window.x1, window.y1)
    chosen = choose_candidates(
        [(float(x), float(y)) for x, y in anchors],
        sizes, obstacles, frame, first_choice, pixels_per_point,
    )  # fmt: skip
    for point, text, index in zip(points, texts, chosen, strict=True):
        where = CANDIDATES[index]
        leader = {"arrowstyle": "-", "color": "0.35", "linewidth": 0.6} if where.far else None
        axes.annotate(text, point, textcoords="offset points", xytext=(where.dx, where.dy),
                      ha=where.ha, va=where.va, fontsize=fontsize, arrowprops=leader)  # fmt: skip
