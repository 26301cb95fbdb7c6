"""Inline SVG charts for the HTML report and the study: grouped bars and a scatter plot.

Plain strings, no JavaScript and no external resources, so a report that embeds them opens
anywhere without a network. Every mark carries its value in a ``data-*`` attribute and a
``<title>`` (tooltip), which is also what the tests read back.
"""

from __future__ import annotations

import math
import textwrap
from collections.abc import Callable, Sequence
from html import escape

#: Colour of the n-th series (Okabe–Ito, readable by colour-blind readers).
PALETTE: tuple[str, ...] = (
    "#0072B2",
    "#E69F00",
    "#009E73",
    "#CC79A7",
    "#56B4E9",
    "#D55E00",
    "#F0E442",
    "#000000",
)

_FONT = 'font-family="sans-serif" font-size="12"'
#: The SVG namespace declaration: inline in HTML a chart needs none, written to a file of its own
#: (shown by ``<img src="chart.svg">`` or a Markdown image) it must have it, or nothing is drawn.
SVG_NS = 'xmlns="http://www.w3.org/2000/svg"'


def svg_file_text(svg: str) -> str:
    """``svg`` (a chart of this module) as the text of a standalone ``.svg`` file: with the
    namespace declaration, which inline charts leave out (a self-contained HTML page then names
    no address at all)."""
    if svg.startswith(f"<svg {SVG_NS}"):
        return svg
    if not svg.startswith("<svg "):
        raise ValueError(f"not an <svg> element: {svg[:40]!r}")
    return f"<svg {SVG_NS} " + svg[len("<svg "):]


def colour(index: int) -> str:
    """Colour of series ``index`` (cycles through :data:`PALETTE`)."""
    return PALETTE[index % len(PALETTE)]


def nice_ticks(low: float, high: float, count: int = 5) -> list[float]:
    """Round tick values covering ``[low, high]`` (1, 2 or 5 times a power of ten apart)."""
    if not (math.isfinite(low) and math.isfinite(high)):
        return []
    if high <= low:
        high = low + (abs(low) if low else 1.0)
    raw = (high - low) / max(count - 1, 1)
    power = 10 ** math.floor(math.log10(raw))
    step = next(m * power for m in (1, 2, 5, 10) if m * power >= raw)
    first = math.floor(low / step) * step
    ticks = []
    value = first
    while value <= high + step * 1e-9:
        ticks.append(round(value, 12))
        value += step
    if ticks[-1] < high:
        ticks.append(round(value, 12))
    return ticks


def _fmt(value: float) -> str:
    return f"{value:.4g}"


def bar_chart(
    groups: Sequence[str],
    series: Sequence[str],
    values: Sequence[Sequence[float | None]],
    low: Sequence[Sequence[float | None]] | None = None,
    high: Sequence[Sequence[float | None]] | None = None,
    *,
    y_label: str = "success %",
    scale: float = 100.0,
    y_max: float = 1.0,
    plot_height: int = 240,
    bar_width: int = 18,
) -> str:
    """Grouped bar chart with optional error bars, as an ``<svg>`` element.

    Args:
        groups: x categories (e.g. tasks), left to right.
        series: One bar per series in every group (e.g. models), with a legend.
        values: ``values[s][g]``: bar height of series ``s`` in group ``g`` in data units;
            ``None`` or NaN: no bar (marked "n/a").
        low: Lower ends of the error bars, same layout (``None``: no error bars).
        high: Upper ends of the error bars.
        y_label: Axis title.
        scale: Tick labels show ``value * scale`` (100: fractions as percent).
        y_max: Top of the axis in data units.
        plot_height: Height of the plotting area in pixels; a bar of value ``v`` is
            ``v / y_max * plot_height`` pixels high.
        bar_width: Width of one bar in pixels.

    Returns:
        The SVG markup. Bars are ``<rect class="bar">`` with ``data-series``,
        ``data-group`` and ``data-value``; error bars are ``<line class="err">``.
    """
    left, top, bottom, gap = 56, 16, 110, 18
    plot_width = max(len(groups) * (len(series) * bar_width + gap), 320)
    group_width = plot_width / max(len(groups), 1)
    legend_width = 24 + max((len(s) for s in series), default=0) * 7
    width = round(left + plot_width + 24 + legend_width)
    height = top + plot_height + bottom
    base = top + plot_height

    def y(v: float) -> float:
        return base - min(max(v, 0.0), y_max) / y_max * plot_height

    parts = [
        f'<svg class="chart bars" width="{width}" '
        f'height="{height}" viewBox="0 0 {width} {height}" role="img" {_FONT}>'
    ]
    for tick in nice_ticks(0.0, y_max, 5):
        if tick > y_max + 1e-9:
            continue
        ty = y(tick)
        parts.append(
            f'<line x1="{left}" y1="{ty:.1f}" x2="{left + plot_width}" y2="{ty:.1f}" '
            'stroke="#ddd"/>'
            f'<text x="{left - 6}" y="{ty + 4:.1f}" text-anchor="end">{_fmt(tick * scale)}</text>'
        )
    parts.append(
        f'<text transform="translate(14,{top + plot_height / 2:.0f}) rotate(-90)" '
        f'text-anchor="middle">{escape(y_label)}</text>'
    )
    for g, group in enumerate(groups):
        x0 = left + g * group_width + (group_width - len(series) * bar_width) / 2
        for s, name in enumerate(series):
            value = values[s][g]
            x = x0 + s * bar_width
            if value is None or math.isnan(value):
                parts.append(
                    f'<text x="{x + bar_width / 2:.1f}" y="{base - 4}" font-size="9" '
                    f'text-anchor="middle" fill="#999">n/a</text>'
                )
                continue
            bar_h = base - y(value)
            tip = f"{name} · {group}: {_fmt(value * scale)}"
            lo = low[s][g] if low is not None else None
            hi = high[s][g] if high is not None else None
            if lo is not None and hi is not None and not (math.isnan(lo) or math.isnan(hi)):
                tip += f" [{_fmt(lo * scale)}, {_fmt(hi * scale)}]"
            parts.append(
                f'<rect class="bar" data-series="{escape(name)}" data-group="{escape(group)}" '
                f'data-value="{value!r}" x="{x + 1:.1f}" y="{base - bar_h:.3f}" '
                f'width="{bar_width - 2}" height="{bar_h:.3f}" fill="{colour(s)}">'
                f"<title>{escape(tip)}</title></rect>"
            )
            if lo is not None and hi is not None and not (math.isnan(lo) or math.isnan(hi)):
                cx = x + bar_width / 2
                parts.append(
                    f'<line class="err" data-series="{escape(name)}" data-group="{escape(group)}" '
                    f'data-low="{lo!r}" data-high="{hi!r}" x1="{cx:.1f}" y1="{y(lo):.3f}" '
                    f'x2="{cx:.1f}" y2="{y(hi):.3f}" stroke="#222" stroke-width="1.5"/>'
                    f'<line x1="{cx - 4:.1f}" y1="{y(lo):.3f}" x2="{cx + 4:.1f}" y2="{y(lo):.3f}" '
                    'stroke="#222"/>'
                    f'<line x1="{cx - 4:.1f}" y1="{y(hi):.3f}" x2="{cx + 4:.1f}" y2="{y(hi):.3f}" '
                    'stroke="#222"/>'
                )
        label_x = x0 + len(series) * bar_width / 2
        parts.append(
            f'<text transform="translate({label_x:.1f},{base + 14}) rotate(30)" '
            f'text-anchor="start">{escape(group)}</text>'
        )
    parts.append(
        f'<line x1="{left}" y1="{base}" x2="{left + plot_width}" y2="{base}" stroke="#444"/>'
    )
    lx = round(left + plot_width + 24)
    for s, name in enumerate(series):
        ly = top + 4 + s * 18
        parts.append(
            f'<rect x="{lx}" y="{ly}" width="12" height="12" fill="{colour(s)}"/>'
            f'<text x="{lx + 18}" y="{ly + 10}">{escape(name)}</text>'
        )
    parts.append("</svg>")
    return "".join(parts)


#: Estimated width of one 11-12 px sans-serif character, and the height of a text line (px).
_CHAR_WIDTH = 6.5
_LINE_HEIGHT = 14


def _free_label_y(
    label: str,
    x: float,
    anchor: str,
    y: float,
    placed: list[tuple[float, float, float, float]],
    y_limits: tuple[float, float],
) -> float:
    """The baseline nearest ``y`` at which ``label``'s box overlaps no box in ``placed`` (which
    it then joins), within ``y_limits``."""
    w = _CHAR_WIDTH * len(label)
    x0, x1 = (x - w, x) if anchor == "end" else (x, x + w)
    lo, hi = y_limits
    for step in range(0, 40):
        shift = (step + 1) // 2 * (1 if step % 2 else -1) * 12  # 0, +12, -12, +24, ...
        cand = min(max(y + shift, lo), hi)
        box = (x0, x1, cand - 11, cand + 2)
        if all(
            box[1] <= b[0] or box[0] >= b[1] or box[3] <= b[2] or box[2] >= b[3] for b in placed
        ):
            placed.append(box)
            return cand
    placed.append((x0, x1, y - 11, y + 2))
    return y


def _grid(
    x_ticks: Sequence[float],
    y_ticks: Sequence[float],
    px: Callable[[float], float],
    py: Callable[[float], float],
    box: tuple[float, float, float, float],
    x_label: str,
    y_label: str,
    y_scale: float = 1.0,
) -> str:
    """Grid lines with tick labels, the plot's frame and both axis titles (``box``: left,
    top, width and height of the plotting area; tick labels of y show ``tick * y_scale``)."""
    left, top, pw, ph = box
    parts = []
    for tick in y_ticks:
        ty = py(tick)
        parts.append(
            f'<line x1="{left}" y1="{ty:.1f}" x2="{left + pw}" y2="{ty:.1f}" stroke="#eee"/>'
            f'<text x="{left - 6}" y="{ty + 4:.1f}" text-anchor="end">{_fmt(tick * y_scale)}</text>'
        )
    for tick in x_ticks:
        tx = px(tick)
        parts.append(
            f'<line x1="{tx:.1f}" y1="{top}" x2="{tx:.1f}" y2="{top + ph}" stroke="#eee"/>'
            f'<text x="{tx:.1f}" y="{top + ph + 16}" text-anchor="middle">{_fmt(tick)}</text>'
        )
    height = top + ph + 44
    parts.append(
        f'<rect x="{left}" y="{top}" width="{pw}" height="{ph}" fill="none" stroke="#444"/>'
        f'<text x="{left + pw / 2:.0f}" y="{height - 8}" text-anchor="middle">'
        f"{escape(x_label)}</text>"
        f'<text transform="translate(14,{top + ph / 2:.0f}) rotate(-90)" text-anchor="middle">'
        f"{escape(y_label)}</text>"
    )
    return "".join(parts)


def scatter_plot(
    points: Sequence[tuple[str, float, float]],
    *,
    x_label: str,
    y_label: str = "success %",
    y_scale: float = 100.0,
    y_range: tuple[float, float] = (0.0, 1.0),
    title: str = "",
    size: tuple[int, int] = (360, 260),
) -> str:
    """Labelled scatter plot as an ``<svg>`` element.

    Args:
        points: ``(label, x, y)`` per point (e.g. a model's metric and success).
        x_label: Axis title of x (the metric).
        y_label: Axis title of y.
        y_scale: Tick labels of y show ``y * y_scale``.
        y_range: y axis range in data units.
        title: Caption drawn above the plot.
        size: Width and height of the plotting area in pixels.

    Returns:
        The SVG markup; points are ``<circle class="pt">`` with ``data-label``, ``data-x``
        and ``data-y``.
    """
    left, right, bottom = 60, 24, 44
    pw, ph = size
    width = left + pw + right
    # The caption wraps to the figure's width instead of running off its right edge.
    title_lines = textwrap.wrap(title, max(10, int((width - 8) / _CHAR_WIDTH))) if title else []
    top = 28 + _LINE_HEIGHT * max(0, len(title_lines) - 1)
    height = top + ph + bottom
    xs = [p[1] for p in points if math.isfinite(p[1])]
    # Pad the data range so that no point (or its label) sits on the frame.
    pad = 0.08 * ((max(xs) - min(xs)) or abs(xs[0]) or 1.0) if xs else 0.0
    x_ticks = nice_ticks(min(xs) - pad, max(xs) + pad, 5) if xs else [0.0, 1.0]
    x_lo, x_hi = x_ticks[0], x_ticks[-1]
    if x_hi <= x_lo:
        x_hi = x_lo + 1.0
    y_lo, y_hi = y_range

    def px(v: float) -> float:
        return left + (v - x_lo) / (x_hi - x_lo) * pw

    def py(v: float) -> float:
        return top + ph - (min(max(v, y_lo), y_hi) - y_lo) / (y_hi - y_lo) * ph

    parts = [
        f'<svg class="chart scatter" width="{width}" '
        f'height="{height}" viewBox="0 0 {width} {height}" role="img" {_FONT}>'
    ]
    for n, line in enumerate(title_lines):
        parts.append(
            f'<text x="4" y="{16 + n * _LINE_HEIGHT}" font-weight="bold">{escape(line)}</text>'
        )
    y_ticks = [t for t in nice_ticks(y_lo, y_hi, 5) if t <= y_hi + 1e-9]
    parts.append(_grid(x_ticks, y_ticks, px, py, (left, top, pw, ph), x_label, y_label, y_scale))
    placed: list[tuple[float, float, float, float]] = []
    for i, (label, x, yv) in enumerate(points):
        if not (math.isfinite(x) and math.isfinite(yv)):
            continue
        cx, cy = px(x), py(yv)
        # Labels point into the plot: left of points in its right half, below points at its top;
        # a label that would overlap one already drawn moves down or up a line at a time.
        right_half = cx > left + pw / 2
        tx, anchor = (cx - 7, "end") if right_half else (cx + 7, "start")
        ty = _free_label_y(
            label, tx, anchor, cy + 16 if cy < top + 16 else cy - 6, placed, (top + 11, top + ph)
        )
        parts.append(
            f'<circle class="pt" data-label="{escape(label)}" data-x="{x!r}" data-y="{yv!r}" '
            f'cx="{cx:.2f}" cy="{cy:.2f}" r="5" fill="{colour(i)}">'
            f"<title>{escape(f'{label}: {_fmt(x)}, {_fmt(yv * y_scale)}')}</title></circle>"
            f'<text x="{tx:.1f}" y="{ty:.1f}" text-anchor="{anchor}" font-size="11">'
            f"{escape(label)}</text>"
        )
    parts.append("</svg>")
    return "".join(parts)


def line_chart(
    series: dict[str, Sequence[tuple[float, float, float, float]]],
    *,
    x_label: str,
    y_label: str,
    reference: tuple[float, str] | None = None,
    title: str = "",
    size: tuple[int, int] = (420, 260),
    x_log: bool = False,
) -> str:
    """Lines with interval bars, one per series, as an ``<svg>`` element (e.g. a measurement
    along training).

    Args:
        series: Label -> ``(x, y, y_low, y_high)`` points (drawn in increasing ``x``).
        x_label: Axis title of x.
        y_label: Axis title of y.
        reference: ``(y, label)`` of a dashed horizontal line (a target).
        title: Caption drawn above the plot.
        size: Width and height of the plotting area in pixels.
        x_log: A logarithmic x axis, ticks at the powers of ten around the points (for
            quantities that span decades, e.g. parameters or trajectories).

    Returns:
        The SVG markup; points are ``<circle class="pt">`` with ``data-series``, ``data-x``,
        ``data-y``, ``data-low`` and ``data-high``; the legend lists the series in order.

    Raises:
        ValueError: ``x_log`` with an x that is not positive.
    """
    left, right, bottom = 60, 150, 44
    pw, ph = size
    width = left + pw + right
    title_lines = textwrap.wrap(title, max(10, int((width - 8) / _CHAR_WIDTH))) if title else []
    top = 28 + _LINE_HEIGHT * max(0, len(title_lines) - 1)
    height = top + ph + bottom
    pts = [p for ps in series.values() for p in ps if all(math.isfinite(v) for v in p)]
    xs = [p[0] for p in pts] or ([1.0, 10.0] if x_log else [0.0, 1.0])
    ys = [v for p in pts for v in p[1:]] + ([reference[0]] if reference else [])
    ys = ys or [0.0, 1.0]
    if x_log:
        bad = [x for x in xs if not x > 0]
        if bad:
            raise ValueError(f"x_log: every x must be positive, got {bad}")
        first, last = math.floor(math.log10(min(xs))), math.ceil(math.log10(max(xs)))
        x_ticks = [10.0**e for e in range(first, max(last, first + 1) + 1)]
    else:
        x_ticks = nice_ticks(min(0.0, min(xs)), max(xs), 5)
    y_ticks = nice_ticks(min(ys), max(ys), 5)
    x_lo, x_hi = x_ticks[0], x_ticks[-1]
    y_lo, y_hi = y_ticks[0], y_ticks[-1]
    if x_hi <= x_lo:
        x_hi = x_lo + 1.0
    if y_hi <= y_lo:
        y_hi = y_lo + 1.0
    to_axis = math.log10 if x_log else float
    a_lo, a_hi = to_axis(x_lo), to_axis(x_hi)

    def px(v: float) -> float:
        return left + (to_axis(v) - a_lo) / (a_hi - a_lo) * pw

    def py(v: float) -> float:
        return top + ph - (v - y_lo) / (y_hi - y_lo) * ph

    parts = [
        f'<svg class="chart lines" width="{width}" '
        f'height="{height}" viewBox="0 0 {width} {height}" role="img" {_FONT}>'
        f'<rect width="{width}" height="{height}" fill="white"/>'
    ]
    for n, line in enumerate(title_lines):
        parts.append(
            f'<text x="4" y="{16 + n * _LINE_HEIGHT}" font-weight="bold">{escape(line)}</text>'
        )
    parts.append(_grid(x_ticks, y_ticks, px, py, (left, top, pw, ph), x_label, y_label))
    if reference is not None:
        ry = py(reference[0])
        parts.append(
            f'<line class="reference" x1="{left}" y1="{ry:.1f}" x2="{left + pw}" y2="{ry:.1f}" '
            f'stroke="#444" stroke-dasharray="5,4"/>'
            f'<text x="{left + pw - 4}" y="{ry - 4:.1f}" text-anchor="end" font-size="11">'
            f"{escape(reference[1])}</text>"
        )
    for i, (name, points) in enumerate(series.items()):
        c = colour(i)
        good = sorted(p for p in points if all(math.isfinite(v) for v in p))
        if len(good) > 1:
            path = " ".join(f"{px(x):.1f},{py(y):.1f}" for x, y, _, _ in good)
            parts.append(f'<polyline points="{path}" fill="none" stroke="{c}" stroke-width="2"/>')
        for x, y, lo, hi in good:
            parts.append(
                f'<line x1="{px(x):.1f}" y1="{py(lo):.1f}" x2="{px(x):.1f}" y2="{py(hi):.1f}" '
                f'stroke="{c}"/>'
                f'<circle class="pt" data-series="{escape(name)}" data-x="{x!r}" data-y="{y!r}" '
                f'data-low="{lo!r}" data-high="{hi!r}" cx="{px(x):.2f}" cy="{py(y):.2f}" r="4" '
                f'fill="{c}"><title>{escape(f"{name}: {_fmt(x)}, {_fmt(y)} [{_fmt(lo)}, {_fmt(hi)}]")}'
                "</title></circle>"
            )
        ly = top + 12 + 18 * i
        parts.append(
            f'<line x1="{left + pw + 12}" y1="{ly - 4}" x2="{left + pw + 32}" y2="{ly - 4}" '
            f'stroke="{c}" stroke-width="2"/>'
            f'<text class="legend" x="{left + pw + 38}" y="{ly}">{escape(name)}</text>'
        )
    parts.append("</svg>")
    return "".join(parts)
