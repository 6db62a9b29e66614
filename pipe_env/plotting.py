"""Matplotlib views of a network: top (x-y) and side (x-z) projections with pipe outlines.

Pipes are drawn as their projected centrelines with the true bore width, fittings are marked by
kind, and the start pose and goals are shown. Optional overlays: a driven path (N, 3) and
decision points. Works headless (Agg backend).
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike

if TYPE_CHECKING:
    from matplotlib.axes import Axes
    from matplotlib.figure import Figure

    from pipe_env.network import PipeNetwork

FITTING_STYLE = {
    "closure": ("s", "#444444"),
    "reducer": ("D", "#8e44ad"),
    "bend": ("o", "#2874a6"),
    "tee": ("^", "#c0392b"),
    "wye": ("v", "#d35400"),
    "cross": ("P", "#16a085"),
}
_VIEWS = {"top": (0, 1, "x [m]", "y [m]"), "side": (0, 2, "x [m]", "z [m]")}


def draw_network(
    ax: Axes,
    network: PipeNetwork,
    view: str = "top",
    path: ArrayLike | None = None,
    decisions: Sequence[ArrayLike] = (),
    samples_per_metre: int = 200,
) -> None:
    """Draw one projection of ``network`` on ``ax`` (``view`` is ``"top"`` or ``"side"``)."""
    if view not in _VIEWS:
        raise ValueError(f"view must be one of {sorted(_VIEWS)}, got {view!r}")
    i, j, xl, yl = _VIEWS[view]
    cl = network.centreline
    # bore as a thick translucent line in data units: convert metres to points via the axes
    for piece in cl.pieces:
        n = max(2, int(piece.length * samples_per_metre))
        pts = np.array([piece.point_tangent(s)[0] for s in np.linspace(0, piece.length, n)])
        ax.plot(pts[:, i], pts[:, j], color="#7f8c8d", lw=1.0, zorder=2)
        _bore_band(ax, pts[:, [i, j]], piece.d0, piece.d1)
    for f in network.fittings:
        marker, colour = FITTING_STYLE[f.kind]
        ax.plot(
            f.position[i], f.position[j], marker=marker, color=colour, ms=6, zorder=4, ls="none"
        )
    if network.start_pose is not None:
        p, fwd = network.start_pose.position, network.start_pose.forward
        ax.annotate(
            "",
            xy=(p[i] + 0.15 * fwd[i], p[j] + 0.15 * fwd[j]),
            xytext=(p[i], p[j]),
            arrowprops={"arrowstyle": "->", "color": "#27ae60", "lw": 2},
            zorder=5,
        )
        ax.plot(p[i], p[j], "o", color="#27ae60", ms=5, zorder=5)
    for g in network.goals:
        ax.plot(g[i], g[j], "*", color="#f1c40f", mec="k", ms=14, zorder=6)
    if path is not None:
        pts = np.asarray(path, dtype=float)
        if len(pts):
            ax.plot(pts[:, i], pts[:, j], color="#e74c3c", lw=1.5, zorder=7)
    for d in decisions:
        d = np.asarray(d, dtype=float)
        ax.plot(d[i], d[j], "x", color="k", ms=8, mew=2, zorder=8)
    ax.set_aspect("equal", adjustable="datalim")
    ax.set_xlabel(xl)
    ax.set_ylabel(yl)
    ax.grid(True, alpha=0.3)


def legend_handles(
    network: PipeNetwork, path: ArrayLike | None = None, decisions: Sequence[ArrayLike] = ()
) -> list[Any]:
    """Legend entries for what :func:`draw_network` draws of ``network`` (only the fitting
    kinds it has, the start, goals, driven path and decisions when present)."""
    from matplotlib.lines import Line2D
    from matplotlib.patches import Patch

    handles: list[Any] = [Patch(color="#bdc3c7", alpha=0.6, label="pipe bore")]
    for kind in sorted({f.kind for f in network.fittings}):
        marker, colour = FITTING_STYLE[kind]
        handles.append(Line2D([], [], marker=marker, color=colour, ls="none", ms=6, label=kind))
    if network.start_pose is not None:
        handles.append(Line2D([], [], marker="o", color="#27ae60", ls="none", ms=5, label="start"))
    if network.goals:
        handles.append(
            Line2D([], [], marker="*", color="#f1c40f", mec="k", ls="none", ms=12, label="goal")
        )
    if path is not None and len(np.asarray(path)):
        handles.append(Line2D([], [], color="#e74c3c", lw=1.5, label="driven path"))
    if len(decisions):
        handles.append(
            Line2D([], [], marker="x", color="k", ls="none", ms=8, mew=2, label="decision")
        )
    return handles


def _bore_band(ax: Axes, pts2: np.ndarray, d0: float, d1: float) -> None:
    """Shade the projected bore of a centreline piece (width = diameter across the projection)."""
    if len(pts2) < 2:
        return
    seg = np.diff(pts2, axis=0)
    norm = np.linalg.norm(seg, axis=1)
    if norm.max() < 1e-9:
        return  # piece is perpendicular to the view
    t = seg / np.maximum(norm, 1e-12)[:, None]
    t = np.vstack([t, t[-1:]])
    n = np.column_stack([-t[:, 1], t[:, 0]])
    d = np.linspace(d0, d1, len(pts2))[:, None] * 0.5
    upper, lower = pts2 + n * d, pts2 - n * d
    poly = np.vstack([upper, lower[::-1]])
    ax.fill(poly[:, 0], poly[:, 1], color="#bdc3c7", alpha=0.6, lw=0, zorder=1)


def plot_network(
    network: PipeNetwork,
    path: ArrayLike | None = None,
    decisions: Sequence[ArrayLike] = (),
    title: str | None = None,
) -> Figure:
    """A figure with the top and side views of ``network`` (and optional path/decisions)."""
    import matplotlib

    matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(13, 6))
    for ax, view in zip(axes, ("top", "side")):
        draw_network(ax, network, view, path, decisions)
        ax.set_title(f"{view} view")
    fig.suptitle(
        title
        or f"{network.name}: {len(network.fittings)} fittings, "
        f"{network.total_length():.2f} m of pipe"
    )
    handles = legend_handles(network, path, decisions)
    fig.legend(handles=handles, loc="lower center", ncol=len(handles), frameon=False)
    fig.tight_layout(rect=(0, 0.06, 1, 1))
    return fig


def save_network_plot(network: PipeNetwork, filename: str | Path, **kwargs: object) -> Path:
    """Write :func:`plot_network` to ``filename`` (PNG/SVG/PDF by suffix) and return the path."""
    import matplotlib.pyplot as plt

    fig = plot_network(network, **kwargs)  # type: ignore[arg-type]
    out = Path(filename)
    out.parent.mkdir(parents=True, exist_ok=True)
    save_figure(fig, out, dpi=120)
    plt.close(fig)
    return out


def save_figure(fig: Any, filename: str | Path, **kwargs: Any) -> Path:
    """``fig.savefig`` written atomically (format from the suffix: png, svg, pdf, ...)."""
    from detector.atomic import atomic_open

    out = Path(filename)
    kwargs.setdefault("format", out.suffix.lstrip(".").lower() or "png")
    with atomic_open(out, "wb") as handle:
        fig.savefig(handle, **kwargs)
    return out
