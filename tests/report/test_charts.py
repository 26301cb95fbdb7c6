"""The report's SVG charts: captions fit, point labels do not overlap, each is an SVG file."""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET

import pytest

from vp2.report.charts import _CHAR_WIDTH, bar_chart, line_chart, scatter_plot, svg_file_text


def _labels(svg: str) -> list[tuple[float, float, str, str]]:
    pattern = r'<text x="([\d.]+)" y="([\d.]+)" text-anchor="(start|end)" font-size="11">([^<]*)'
    return [(float(x), float(y), a, t) for x, y, a, t in re.findall(pattern, svg)]


def test_long_scatter_title_wraps_within_the_figure():
    title = "RoboDesk: success versus FVD over all tasks and seeds (lower FVD is better)"
    svg = scatter_plot([("a", 1.0, 0.5)], x_label="FVD", title=title)
    width = float(re.search(r'width="(\d+)"', svg).group(1))
    lines = re.findall(r'<text x="4" y="\d+" font-weight="bold">([^<]*)', svg)
    assert len(lines) == 2 and " ".join(lines) == title
    assert all(4 + _CHAR_WIDTH * len(line) <= width for line in lines)
    # The plot moved down by a line to make room.
    assert re.search(r'<rect x="60" y="42" ', svg)


def test_labels_of_close_points_do_not_overlap():
    points = [
        ("SVG tiny", 1.0, 0.5),
        ("FitVid small", 1.01, 0.5),
        ("MCVD", 1.02, 0.51),
        ("RLF", 3.0, 0.1),
    ]
    labels = _labels(scatter_plot(points, x_label="FVD"))
    assert [t for *_, t in labels] == [p[0] for p in points]
    boxes = []
    for x, y, anchor, text in labels:
        w = _CHAR_WIDTH * len(text)
        x0, x1 = (x - w, x) if anchor == "end" else (x, x + w)
        boxes.append((x0, x1, y - 11, y + 2))
    for i, a in enumerate(boxes):
        for b in boxes[i + 1 :]:
            assert a[1] <= b[0] or a[0] >= b[1] or a[3] <= b[2] or a[2] >= b[3], (a, b)


def test_line_chart_places_points_intervals_and_the_target_by_value():
    series = {"a": [(30.0, 1.2, 1.1, 1.3), (15.0, 1.0, 0.9, 1.1)], "b": [(15.0, 1.5, 1.4, 1.6)]}
    svg = line_chart(series, x_label="min", y_label="ratio", reference=(1.1, "target 1.1"))
    pts = re.findall(
        r'data-series="(\w)" data-x="([\d.]+)" data-y="([\d.]+)" data-low="([\d.]+)" '
        r'data-high="([\d.]+)" cx="([\d.]+)" cy="([\d.]+)"',
        svg,
    )
    assert [(s, float(x)) for s, x, *_ in pts] == [("a", 15.0), ("a", 30.0), ("b", 15.0)]
    cy = {(s, float(x)): float(y) for s, x, _, _, _, _, y in pts}
    cx = {(s, float(x)): float(v) for s, x, _, _, _, v, _ in pts}
    # Higher values sit higher (smaller y); later points further right.
    assert cy[("b", 15.0)] < cy[("a", 30.0)] < cy[("a", 15.0)]
    assert cx[("a", 30.0)] > cx[("a", 15.0)] == cx[("b", 15.0)]
    ref = float(re.search(r'class="reference" x1="[\d.]+" y1="([\d.]+)"', svg).group(1))
    assert cy[("a", 15.0)] > ref > cy[("a", 30.0)]  # 1.0 below the 1.1 line, 1.2 above
    assert re.findall(r'class="legend"[^>]*>(\w)<', svg) == ["a", "b"]


@pytest.mark.parametrize("kind", ["bars", "scatter", "lines"])
def test_every_chart_written_to_a_file_is_an_svg_document(kind):
    # Shown as an image (docs/paper.md's bars), an <svg> without the SVG namespace is plain XML
    # to a browser: nothing is drawn.
    if kind == "bars":
        svg = bar_chart(["push", "mean"], ["a", "b"], [[1.0, 0.5], [0.0, None]])
    elif kind == "scatter":
        svg = scatter_plot([("m1", 0.1, 0.5), ("m2", 0.3, 0.2)], x_label="FVD", y_label="success")
    else:
        svg = line_chart({"a": [(1.0, 0.5, 0.4, 0.6)]}, x_label="min", y_label="ratio")
    text = svg_file_text(svg)
    root = ET.fromstring(text)
    assert root.tag == "{http://www.w3.org/2000/svg}svg"
    assert svg_file_text(text) == text  # already a file's text: unchanged
    assert root.get("class") == f"chart {kind}"
    assert root.findall(".//{http://www.w3.org/2000/svg}text")


def test_a_logarithmic_x_axis_spaces_decades_evenly():
    series = {"ours": [(5e5, 0.4, 0.3, 0.4), (5e6, 0.1, 0.1, 0.2)], "paper": [(8.3e7, 0.8, 0.8, 0.8)]}
    svg = line_chart(series, x_label="parameters", y_label="success", x_log=True)
    cx = {float(x): float(v) for x, v in re.findall(r'data-x="([\d.e+]+)"[^>]* cx="([\d.]+)"', svg)}
    # One decade is the same width wherever it lies: 5e5 -> 5e6 as wide as 1e5 -> 1e6.
    grid = r'<line x1="([\d.]+)" y1="\d+" x2="[\d.]+" y2="\d+" stroke="#eee"/>'  # x ticks
    ticks = [float(t) for t in re.findall(grid, svg)]
    decade = ticks[1] - ticks[0]
    assert len(ticks) == 4
    assert all(abs((b - a) - decade) < 0.2 for a, b in zip(ticks, ticks[1:], strict=False))
    assert abs((cx[5e6] - cx[5e5]) - decade) < 0.2
    assert ticks[0] < cx[5e5] < ticks[1] < cx[5e6] < ticks[2] < cx[8.3e7] < ticks[3]
    with pytest.raises(ValueError, match="positive"):
        line_chart({"a": [(0.0, 0.5, 0.4, 0.6)]}, x_label="n", y_label="s", x_log=True)
    empty = line_chart({"a": []}, x_label="n", y_label="s", x_log=True)  # nothing measured yet
    assert 'class="pt"' not in empty and ">1<" in empty and ">10<" in empty
