"""What the run's figures share: a figure on the Agg canvas (no pyplot), its layout, saving, the
time window, log axes labelled without mathtext, and whether the run was in virtual time.
Matplotlib is imported inside the functions.

The figures are laid out here rather than by matplotlib's constrained layout, which measures
every axis twice before the figure is drawn (as long as drawing it): :class:`Ruler` measures
the few texts and tick labels around the axes once and :func:`place_column` puts the axes in
one column with those margins, the pads constrained layout would leave. A figure and its axes
can be made before the data is there (:func:`make_ahead`, in the plotting process prestarted
before a show), and :func:`save` writes the PNG (Pillow, three bytes a pixel, zlib's fastest level).
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from hilsim.telemetry.reader import Run

if TYPE_CHECKING:
    from matplotlib.figure import Figure
    from matplotlib.legend import Legend


#: summary.json's "clock" for a run on the emulator's virtual clock
VIRTUAL_CLOCK = "virtual time"


#: the pad (in) constrained layout leaves around each element (its h_pad/w_pad default)
PAD = 3 / 72
#: a tick (3.5 pt) and the gap to its label (3.5 pt); an axis label's pad (4 pt); an axes
#: title's pad (6 pt); in inches (matplotlib's defaults)
TICK, LABEL_PAD, TITLE_PAD = 7 / 72, 4 / 72, 6 / 72


def new_figure(width: float, height: float, dpi: float = 110) -> Figure:
    """An empty figure on the Agg canvas, at the resolution it will be saved at (text is
    measured once, at that size)."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=dpi)
    FigureCanvasAgg(fig)
    return fig


#: figures made before their data (:func:`make_ahead`), by their :func:`figure_axes` arguments
_AHEAD: dict[tuple[float, float, float, int, bool], list[tuple[Figure, list[Any]]]] = {}

#: Tick objects :func:`make_ahead` gives each axes: major x, major y, and minor y where asked
#: (a log axis's 2-9 of each decade); the demo's figures use up to 11, 9 and 48
AHEAD_TICKS = (12, 10, 48)


def figure_axes(
    width: float, height: float, dpi: float, rows: int, *, sharex: bool = False
) -> tuple[Figure, list[Any]]:
    """A new figure (:func:`new_figure`) with ``rows`` axes in one column (``subplots``); the
    one :func:`make_ahead` made with the same arguments, if it is waiting."""
    waiting = _AHEAD.get((width, height, dpi, rows, sharex))
    if waiting:
        return waiting.pop()
    fig = new_figure(width, height, dpi)
    return fig, list(fig.subplots(rows, 1, sharex=sharex, squeeze=False)[:, 0])


def make_ahead(
    width: float,
    height: float,
    dpi: float,
    rows: int,
    *,
    sharex: bool = False,
    minor_y: tuple[int, ...] = (),
) -> None:
    """Make now, before the data is there, the figure a later :func:`figure_axes` call with
    the same arguments returns, with Tick objects on its axes (:data:`AHEAD_TICKS`; minor y
    ones on the axes numbered in ``minor_y``). Matplotlib makes the ticks it lacks while it
    draws, a quarter of a figure's drawing time, and uses the ones it has, which follow every
    later setting as new ones would: the picture is the same (tests/hilsim/test_plot_speed.py).
    The plotting process prestarted before a show calls this while the show runs."""
    fig = new_figure(width, height, dpi)
    axes = list(fig.subplots(rows, 1, sharex=sharex, squeeze=False)[:, 0])
    major_x, major_y, minor = AHEAD_TICKS
    for i, ax in enumerate(axes):
        ax.xaxis.get_major_ticks(major_x)
        ax.yaxis.get_major_ticks(major_y)
        if i in minor_y:
            ax.yaxis.get_minor_ticks(minor)
    _AHEAD.setdefault((width, height, dpi, rows, sharex), []).append((fig, axes))


def title(fig: Figure, text: str) -> Any:
    """The figure's title, top left, one pad below the edge."""
    return fig.suptitle(text, x=0.01, y=1 - PAD / fig.get_figheight(), ha="left", va="top")


class Ruler:
    """Sizes in inches of what sits around a figure's axes, from its renderer."""

    def __init__(self, fig: Figure) -> None:
        self.fig = fig
        # new_figure()'s Agg canvas has a renderer; matplotlib types fig.canvas as the base
        self.renderer = fig.canvas.get_renderer()  # type: ignore[attr-defined]
        self._texts: dict[tuple[str, str], tuple[float, float]] = {}

    def size(self, artist: Any) -> tuple[float, float]:
        """(width, height) of a text or legend; (0, 0) for None, hidden or empty."""
        if artist is None or not artist.get_visible():
            return 0.0, 0.0
        if hasattr(artist, "get_text") and not artist.get_text():
            return 0.0, 0.0
        box = artist.get_window_extent(self.renderer)
        return box.width / self.fig.dpi, box.height / self.fig.dpi

    def tick_labels(self, axis: Any) -> tuple[float, float]:
        """(width, height) of the widest and tallest major tick label of ``axis`` (an Axis) at
        its current limits and length."""
        lo, hi = sorted(axis.get_view_interval())
        slack = 1e-9 * (hi - lo)
        locs = [v for v in axis.get_major_locator()() if lo - slack <= v <= hi + slack]
        labels = [s for s in axis.get_major_formatter().format_ticks(locs) if s] or ["0"]
        name = "xtick" if axis.axis_name == "x" else "ytick"
        sizes = [self._text(s, name) for s in labels]
        return max(w for w, _ in sizes), max(h for _, h in sizes)

    def _text(self, text: str, kind: str) -> tuple[float, float]:
        """(width, height) of ``text`` in ``kind`` (xtick, ytick)'s label font; the height of a
        line, as matplotlib lays out labels ("lp": ascender to descender)."""
        import matplotlib as mpl
        from matplotlib.font_manager import FontProperties

        if (text, kind) not in self._texts:
            key: Literal["xtick.labelsize", "ytick.labelsize"] = (
                "xtick.labelsize" if kind == "xtick" else "ytick.labelsize"
            )
            prop = FontProperties(size=mpl.rcParams[key])
            measure = self.renderer.get_text_width_height_descent
            width = measure(text, prop, ismath=text.count("$") >= 2)[0]
            height = measure("lp", prop, ismath=False)[1]
            self._texts[text, kind] = (width / self.fig.dpi, height / self.fig.dpi)
        return self._texts[text, kind]

    def offset(self, axis: Any) -> float:
        """Height (in) of the text a y axis shows above itself for large values (``1e6``),
        with its pad; 0 when there is none."""
        self.tick_labels(axis)  # sets the formatter's ticks, hence its offset
        text = getattr(axis.get_major_formatter(), "get_offset", str)()
        return self._text(text, "ytick")[1] + LABEL_PAD if text else 0.0

    def left(self, ax: Any) -> float:
        """From the left edge of ``ax`` to the left of its y tick labels and y label."""
        return TICK + self.tick_labels(ax.yaxis)[0] + LABEL_PAD + self.size(ax.yaxis.label)[0]

    def below(self, ax: Any) -> float:
        """From the bottom edge of ``ax`` to the bottom of its x tick labels and x label."""
        return TICK + self.tick_labels(ax.xaxis)[1] + LABEL_PAD + self.size(ax.xaxis.label)[1]


def legend_pad(legend: Legend) -> float:
    """The gap (in) between a legend and the point it is anchored to (its borderaxespad)."""
    return legend.borderaxespad * legend.prop.get_size_in_points() / 72


def place_column(
    fig: Figure,
    axes: list[Any],
    *,
    left: float,
    right: float,
    top: float,
    bottom: float,
    gaps: list[float] | None = None,
    ratios: list[float] | None = None,
) -> None:
    """Put ``axes`` in one column, top to bottom: margins and the gaps between rows in inches
    (each plus :data:`PAD` from the figure's edge), row heights in ``ratios``."""
    width, height = fig.get_size_inches()
    gaps = gaps if gaps is not None else [0.0] * (len(axes) - 1)
    ratios = ratios or [1.0] * len(axes)
    left, right, top, bottom = (m + PAD for m in (left, right, top, bottom))
    free = max(height - top - bottom - sum(gaps), 0.05 * height)
    inner = max(width - left - right, 0.05 * width)
    y = height - top
    for i, ax in enumerate(axes):
        rows = free * ratios[i] / sum(ratios)
        y -= rows
        ax.set_position((left / width, y / height, inner / width, rows / height))
        y -= gaps[i] if i < len(gaps) else 0.0


def save(fig: Figure, path: Path, dpi: float) -> Path:
    """Draw ``fig`` (made at ``dpi``: :func:`new_figure`) and write it as a PNG: the pixels
    ``savefig`` would write, through Pillow as savefig does, but three bytes a pixel when
    every pixel is opaque and zlib's fastest level (the figures' flat colours compress
    about as well; about half the time, docs/performance.md)."""
    import matplotlib as mpl
    from PIL import Image
    from PIL.PngImagePlugin import PngInfo

    path.parent.mkdir(parents=True, exist_ok=True)
    if fig.dpi != dpi:  # not drawn at that size: matplotlib's own way
        fig.savefig(path, dpi=dpi)
        return path
    fig.canvas.draw()
    rgba = np.asarray(fig.canvas.buffer_rgba())  # type: ignore[attr-defined]  # (Agg's canvas)
    opaque = bool((rgba[:, :, 3] == 255).all())
    image = Image.fromarray(np.ascontiguousarray(rgba[:, :, :3]) if opaque else rgba)
    info = PngInfo()
    info.add_text("Software", f"Matplotlib version{mpl.__version__}, https://matplotlib.org/")
    image.save(path, format="PNG", compress_level=1, dpi=(dpi, dpi), pnginfo=info)
    return path


_SUPERSCRIPT = str.maketrans("0123456789-", "⁰¹²³⁴⁵⁶⁷⁸⁹⁻")


def _plain(label: str) -> str:
    r"""Matplotlib's log tick label (``$\mathdefault{2\times10^{3}}$``) as plain text (2×10³)."""
    if not (label.startswith("$\\mathdefault{") and label.endswith("}$")):
        return label
    body = label[len("$\\mathdefault{") : -2].replace("\\times", "×")
    base, hat, exponent = body.partition("^{")
    return base + exponent.rstrip("}").translate(_SUPERSCRIPT) if hat else body


def log_axis(axis: Any) -> None:
    """Label ``axis`` (an Axis on a base-10 log scale) 10³, 2×10³ in plain text: the labels
    matplotlib's defaults would draw, without building its mathtext parser (a tenth of a second).
    """
    from matplotlib.ticker import LogFormatterSciNotation

    class PlainLogFormatter(LogFormatterSciNotation):
        def __call__(self, x: float, pos: int | None = None) -> str:
            return _plain(super().__call__(x, pos))

    # the log scale's defaults: both LogFormatterSciNotation(10), minor ticks labelled only when
    # the axis spans about a decade or less
    axis.set_major_formatter(PlainLogFormatter())
    axis.set_minor_formatter(PlainLogFormatter())


def window(run: Run, start: float | None, end: float | None) -> np.ndarray:
    t = run.t_sched
    keep = np.ones(t.shape, dtype=bool)
    if start is not None:
        keep &= t >= start
    if end is not None:
        keep &= t <= end
    return keep


def rows_in(run: Run, keep: np.ndarray) -> int:
    """The ticks' rows in the window ``keep`` (a decimated run: counted, two rows a bucket)."""
    if run.counts is not None:
        return int(run.counts["rows"][keep].sum())
    return int(np.count_nonzero(keep))


def period_s(run: Run) -> float:
    """The time between two ticks, from the rows (0 with fewer than two)."""
    t, tick = run.t_sched, run.columns["tick"]
    if t.size < 2 or tick[-1] <= tick[0]:
        return 0.0
    return float((t[-1] - t[0]) / (tick[-1] - tick[0]))


def decimation_note(run: Run) -> str:
    """A title's note on a bounded read: what a drawn point stands for."""
    env = run.envelope
    rot = (run.summary or {}).get("telemetry") or {}
    rot = rot.get("rotation") if isinstance(rot, dict) else None
    gone = rot.get("rows_removed") if isinstance(rot, dict) else None
    cap = f"\nthe oldest {gone:,} rows were removed under the run's cap" if gone else ""
    if env is None or not env.decimated:
        return cap
    return cap + (
        f"\n{env.rows:,} rows read in bounded memory: drawn as the min and max of every "
        f"{env.width:,} ticks; counts exact, percentiles within 2.3 %"
    )


def window_note(start: float | None, end: float | None) -> str:
    if start is None and end is None:
        return ""
    lo = "start" if start is None else f"{start:g} s"
    hi = "end" if end is None else f"{end:g} s"
    return f", {lo} to {hi}"


def tick_count(run: Run, n: int, start: float | None, end: float | None) -> str:
    """``N ticks`` for a title's ``n`` rows, with `` + K caught up without a row`` for a
    whole run whose loop skipped K ticks' rows to catch up after overruns (its summary's
    ``loop.skipped_ticks``, a positive int; without a summary, as after a crash, what the rows
    count: :attr:`Run.caught_up`), so the count adds up to the end line's (unless rows were
    dropped); a window (``start``/``end``) counts its rows only."""
    if start is not None or end is not None:
        return f"{n} ticks"
    loop = run.summary.get("loop") if isinstance(run.summary, dict) else None
    skipped = loop.get("skipped_ticks") if isinstance(loop, dict) else None
    if run.summary is None:
        skipped = run.caught_up
    more = f" + {skipped} caught up without a row" if type(skipped) is int and skipped > 0 else ""
    return f"{n} ticks{more}"


def is_virtual_time(run: Run) -> bool:
    """True when the run's summary says it ran on the virtual clock."""
    return isinstance(run.summary, dict) and run.summary.get("clock") == VIRTUAL_CLOCK
