"""The figure of an archive, by its kind: the one dispatch behind ``vine-nlp plot``, ``--plot`` and the API's ``plot``."""

from __future__ import annotations

from pathlib import Path

from vine_nlp.front.fit_plots import plot_fit
from vine_nlp.front.multishape_plot import plot_multishape_figure
from vine_nlp.front.plot import figure_format, plot_archive, save_figure
from vine_nlp.io.archive import Archive, load_archive


def figure(archive: Archive, path=None):
    """The matplotlib Figure of ``archive`` (not registered with pyplot): a fit archive gets the fit's own figure
    (measured points against the model, error along it); a multi-shape archive is drawn from its file ``path``
    (its levels are groups the generic reader leaves out)."""
    if archive.kind == "multishape":
        return plot_multishape_figure(path)
    if archive.kind == "fit":
        return plot_fit(archive)
    if archive.kind in ("actuators", "actuators-forward"):
        from vine_nlp.front.actuators_plot import plot_actuators_figure

        return plot_actuators_figure(path)
    return plot_archive(archive, obstacles=archive.obstacles)


def draw(archive_path, figure_path) -> Path:
    """Draw the archive file into ``figure_path`` (png, pdf or svg by suffix), atomically."""
    figure_format(figure_path)  # before any drawing
    return save_figure(figure(load_archive(archive_path), archive_path), figure_path)
