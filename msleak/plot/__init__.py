"""Every msleak figure (matplotlib is imported only in this package).

One module per topic: :mod:`msleak.plot.sky`, :mod:`msleak.plot.beam`,
:mod:`msleak.plot.ps`, :mod:`msleak.plot.leakage`. Each function takes arrays or
products and a path, and writes the figure (PNG, and PDF beside it when asked).
"""

from __future__ import annotations

from pathlib import Path

__all__ = ["new_figure", "save_figure", "figure_formats", "uv_cell_text"]


def _pyplot():
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    return plt


def figure_formats() -> list[str]:
    """File name suffixes (without the dot) that figures can be saved as."""
    from matplotlib.backend_bases import FigureCanvasBase

    return sorted(FigureCanvasBase.get_supported_filetypes())


def uv_cell_text(cell_lambda: float) -> str:
    """How figures name the uv cell size of a power spectrum, with the field it is the
    Fourier dual of: ``uv cell 16 λ (field 1/cell = 3.58°)``. That field is set by the
    gridding, not by the sky: every field of view of a sky gridded on 16-wavelength cells
    shows the same 3.58° (docs/ps.md, "Figures")."""
    import math

    return (f"uv cell {cell_lambda:.3g} λ (field 1/cell = "
            f"{math.degrees(1.0 / cell_lambda):.3g}°)")


def new_figure(*args, **kwargs):
    """``plt.subplots`` with the non-interactive backend; returns (fig, axes)."""
    return _pyplot().subplots(*args, **kwargs)


def save_figure(fig, path, pdf: bool = False, dpi: int = 130) -> Path:
    """Save ``fig`` to ``path`` (and a PDF beside it if ``pdf``, laid out as the first
    file: its layout engine runs once), then close it. A figure with constrained layout
    keeps its size (the layout fits everything in it); others are cropped to what they
    draw."""
    from matplotlib.layout_engine import ConstrainedLayoutEngine

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    engine = fig.get_layout_engine()
    # cropping needs a draw of its own, which would run the layout once more
    bbox = None if isinstance(engine, ConstrainedLayoutEngine) else "tight"
    fig.savefig(path, dpi=dpi, bbox_inches=bbox)
    if pdf and path.suffix.lower() != ".pdf":
        if engine is not None:
            fig.set_layout_engine("none")  # keeps the axes where the layout put them
        fig.savefig(path.with_suffix(".pdf"), bbox_inches=bbox)
    _pyplot().close(fig)
    return path
