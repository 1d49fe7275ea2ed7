"""One task palette, ``osgd.contract.taxonomy.TASK_COLOURS``, in every picture that colours by task.

The pictures are checked through what matplotlib was given: the legend's
colours and the drawn lines' colours must be the palette's floats exactly,
so a picture with a palette of its own (or one rounded through hex) fails.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import matplotlib.pyplot as plt
import numpy as np
import pytest
from helpers import synthetic_sample_row
from matplotlib.collections import LineCollection
from matplotlib.colors import to_rgb
from matplotlib.figure import Figure
from matplotlib.legend import Legend
from matplotlib.lines import Line2D
from test_samples_fixtures import write_fixture_inputs

from osgd.contract.samples import decode_row
from osgd.contract.taxonomy import TASK_COLOURS, TASK_INDEX, TASKS
from osgd.grasps.pictures import show_grasps
from osgd.samples.pictures import draw_sample
from osgd.store import ShardStore


@pytest.fixture
def saved_figures(monkeypatch: pytest.MonkeyPatch) -> list[Figure]:
    """Every figure saved while the test runs, in order (still holding its artists)."""
    figures: list[Figure] = []
    original = Figure.savefig

    def savefig(self: Figure, *args, **kwargs) -> None:
        figures.append(self)
        original(self, *args, **kwargs)

    monkeypatch.setattr(Figure, "savefig", savefig)
    return figures


def line_legend_colours(legend: Legend) -> dict[str, tuple[float, float, float]]:
    """Label -> RGB of the legend's line entries (patches, e.g. part tints, left out)."""
    return {
        text.get_text(): to_rgb(handle.get_color())
        for text, handle in zip(legend.get_texts(), legend.legend_handles, strict=True)
        if isinstance(handle, Line2D)
    }


def test_the_palette_covers_every_task_with_distinct_colours() -> None:
    assert tuple(TASK_COLOURS) == TASKS
    for colour in TASK_COLOURS.values():
        assert len(colour) == 3
        assert all(isinstance(value, float) and 0.0 <= value <= 1.0 for value in colour)
    assert len(set(TASK_COLOURS.values())) == len(TASKS)


def test_the_palette_is_matplotlibs_tab20_written_out() -> None:
    from matplotlib import colormaps  # noqa: PLC0415

    tab20 = colormaps["tab20"].colors
    for task, index in TASK_INDEX.items():
        assert TASK_COLOURS[task] == tuple(tab20[(2 * index) % 20 + (index >= 10)])


def test_sample_pictures_draw_tasks_in_the_palette_colours() -> None:
    sample = decode_row(synthetic_sample_row(np.random.default_rng(0), 0))
    tasks = {TASKS[index] for index in sample.grasp_tasks}
    assert len(tasks) >= 2
    figure, axes = plt.subplots()
    try:
        draw_sample(sample, axes)
        shown = line_legend_colours(axes.get_legend())
        assert set(shown) == tasks
        assert all(colour == TASK_COLOURS[task] for task, colour in shown.items())
        assert {to_rgb(line.get_color()) for line in axes.lines} == {TASK_COLOURS[task] for task in tasks}
    finally:
        plt.close(figure)


def test_grasp_pictures_draw_tasks_in_the_palette_colours(tmp_path: Path, saved_figures: list[Figure]) -> None:
    store = ShardStore(tmp_path / "data")
    write_fixture_inputs(store)
    show_grasps(store, "test/hammer", tmp_path / "hammer.png")
    figure = saved_figures[-1]
    shown = line_legend_colours(figure.legends[0])
    assert set(shown) == {"hammer", "hand over"}
    assert all(colour == TASK_COLOURS[task] for task, colour in shown.items())
    # The first panel shows every grasp; its line collection holds their outline colours.
    lines = next(collection for collection in figure.axes[0].collections if isinstance(collection, LineCollection))
    drawn = {tuple(float(value) for value in rgba[:3]) for rgba in lines.get_colors()}
    assert drawn == {TASK_COLOURS["hammer"], TASK_COLOURS["hand over"]}


def test_prediction_pictures_draw_tasks_in_the_palette_colours(tmp_path: Path, saved_figures: list[Figure]) -> None:
    pytest.importorskip("torch")
    from togcrf.metrics import Detections  # noqa: PLC0415
    from togcrf.predict import draw_prediction, task_colours  # noqa: PLC0415

    assert np.array_equal(task_colours(), np.array([TASK_COLOURS[task] for task in TASKS]))
    task_probs = np.zeros((2, 2, len(TASKS)))
    task_probs[0, :, TASK_INDEX["cut"]] = 1.0
    task_probs[1, :, TASK_INDEX["hand over"]] = 1.0
    grasps = np.tile(np.array([40.0, 40.0, 20.0, 6.0, 0.2]), (2, 2, 1))
    grasps[1, :, 0] = [80.0, 90.0]
    detections = Detections(boxes=np.array([[20.0, 20, 60, 60], [70, 30, 110, 50]]), categories=np.array([0, 1]),
                            scores=np.array([0.9, 0.8]), grasps=grasps, grasp_stability=np.full((2, 2), 0.9),
                            grasp_task_probs=task_probs)
    draw_prediction(np.full((128, 160), 0.8, dtype=np.float32), detections, tmp_path / "prediction.png")
    shown = line_legend_colours(saved_figures[-1].axes[0].get_legend())
    assert shown == {"cut": TASK_COLOURS["cut"], "hand over": TASK_COLOURS["hand over"]}
