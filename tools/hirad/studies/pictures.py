"""Pictures of a study (matplotlib, PNG bytes; no pyplot state, so safe in threads and tests).

* :func:`grid_picture`: a false-colour map of a grid's illuminance in lux, the cells of a
  regular grid drawn as they are (points at their centres), isolux contour lines labelled in
  lux, a colour bar in lux, the floor's outline and the evaluation area (the border band
  outside it). Points from a file are drawn as coloured dots over their horizontal position.
* :func:`luminance_picture`: the counterpart of Radiance's ``falsecolor``: a luminance image
  (H, W) in cd/m^2 mapped to ``steps`` colour bands, linear from 0 to ``maximum`` or
  logarithmic over ``decades`` decades below it (falsecolor -s, -n, -log), with a colour scale
  in cd/m^2 and optional contour lines between the bands (falsecolor -cl). Pixels that are NaN
  (no surface) are grey.
* :func:`camera_luminance_picture`: that picture of a bake's camera view: the solution rendered
  (``Result.render``: exitant radiance, linear RGB) and reduced to Y = 0.2126 R + 0.7152 G +
  0.0722 B, which is luminance in cd/m^2 read photometrically (radiance in W/(m^2 sr) read
  radiometrically, and the legend says so).

Every legend and label names the unit of the study's ``units``: lux and cd/m^2 (photometric,
the default) or W/m^2 and W/(m^2 sr) (radiometric).
"""

from __future__ import annotations

import io
import math
from typing import Optional

import numpy as np

from hirad.files import write_bytes

from .evaluate import GridResult
from .outputs import unit_system
from .spec import StudyError

_PNG_METADATA = {"Software": None}  # the same bytes whatever the matplotlib build


def _figure(width: float, height: float):
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=100)
    FigureCanvasAgg(fig)
    return fig


def _png(fig, dpi: int = 100) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, metadata=_PNG_METADATA, bbox_inches="tight")
    return buf.getvalue()


def nice_ceiling(x: float) -> float:
    """The least of 1, 2, 2.5, 5 x 10^k that is >= x (x > 0)."""
    if not (x > 0 and math.isfinite(x)):
        return 1.0
    k = math.floor(math.log10(x))
    for m in (1.0, 2.0, 2.5, 5.0, 10.0):
        v = m * 10.0 ** k
        if v >= x * (1 - 1e-12):
            return v
    return 10.0 ** (k + 1)


def _isolux_levels(lo: float, hi: float, count: int = 8) -> np.ndarray:
    from matplotlib.ticker import MaxNLocator

    if not (hi > lo):
        return np.array([])
    levels = MaxNLocator(nbins=count, steps=[1, 2, 2.5, 5, 10]).tick_values(lo, hi)
    return levels[(levels > lo) & (levels < hi)]


def grid_picture(result: GridResult, *, title: Optional[str] = None, maintained: bool = False,
                 cmap: str = "viridis", width: float = 7.0, units: str = "photometric") -> bytes:
    """A PNG of the grid's values (lux, or W/m^2 for radiometric `units`; the maintained ones
    if `maintained`)."""
    from matplotlib import colors

    us = unit_system(units)
    unit = us["unit_text"]
    g = result.grid
    values = result.maintained if maintained else result.values
    what = f"maintained {us['quantity']}" if maintained else us["quantity"]
    st = result.stats
    lo, hi = float(np.min(values)), float(np.max(values))
    vmin, vmax = (lo, hi) if hi > lo else (lo - 0.5 if lo >= 0.5 else 0.0, lo + 0.5)
    norm = colors.Normalize(vmin=vmin, vmax=vmax)
    lay = g.layout
    if lay is not None:
        umin, umax, vmin_, vmax_ = lay.evaluation_box
        allpts = np.concatenate([np.asarray(o) for o in lay.outlines]) if lay.outlines else np.array([[umin, vmin_], [umax, vmax_]])
        span_u = max(allpts[:, 0].max() - allpts[:, 0].min(), 1e-9)
        span_v = max(allpts[:, 1].max() - allpts[:, 1].min(), 1e-9)
        height = max(2.5, min(12.0, width * span_v / span_u)) + 0.8
    else:
        height = width * 0.8
    fig = _figure(width, height)
    ax = fig.add_subplot(1, 1, 1)
    if lay is not None:
        arr = np.full((lay.nv, lay.nu), np.nan)
        arr[lay.index[:, 1], lay.index[:, 0]] = values
        ue = lay.u0 - 0.5 * lay.du + lay.du * np.arange(lay.nu + 1)
        ve = lay.v0 - 0.5 * lay.dv + lay.dv * np.arange(lay.nv + 1)
        mesh = ax.pcolormesh(ue, ve, np.ma.masked_invalid(arr), cmap=cmap, norm=norm, shading="flat")
        levels = _isolux_levels(lo, hi)
        if len(levels) and lay.nu >= 2 and lay.nv >= 2:
            uc = lay.u0 + lay.du * np.arange(lay.nu)
            vc = lay.v0 + lay.dv * np.arange(lay.nv)
            cs = ax.contour(uc, vc, np.ma.masked_invalid(arr), levels=levels, colors="white", linewidths=0.9)
            ax.clabel(cs, fmt=lambda v: f"{v:g} {unit}", fontsize=7, inline=True)
        for o in lay.outlines:
            o = np.asarray(o)
            ax.plot(np.r_[o[:, 0], o[0, 0]], np.r_[o[:, 1], o[0, 1]], color="black", linewidth=1.0)
        ax.plot([umin, umax, umax, umin, umin], [vmin_, vmin_, vmax_, vmax_, vmin_], color="black",
                linewidth=0.6, linestyle="--")
        ax.set_aspect("equal")
        ax.set_xlabel("u (m)")
        ax.set_ylabel("v (m)")
    else:
        p = g.points
        # the two world axes along which the points spread most
        spread = p.max(axis=0) - p.min(axis=0)
        a, b = sorted(np.argsort(spread)[-2:])
        mesh = ax.scatter(p[:, a], p[:, b], c=values, cmap=cmap, norm=norm, s=40, edgecolors="black", linewidths=0.3)
        for x, y, v in zip(p[:, a], p[:, b], values):
            ax.annotate(f"{v:.4g}", (x, y), textcoords="offset points", xytext=(4, 4), fontsize=6)
        ax.set_aspect("equal", adjustable="datalim")
        ax.set_xlabel(f"{'xyz'[a]} (m)")
        ax.set_ylabel(f"{'xyz'[b]} (m)")
    cb = fig.colorbar(mesh, ax=ax, shrink=0.85)
    cb.set_label(f"{what} ({unit})")
    u0 = "-" if st.u0 is None else f"{st.u0:.3f}"
    em = st.em_maintained if maintained else st.em
    ax.set_title(title or f"{g.name}: {g.measure.type.replace('_', '-')} {what}, Em {em:.4g} {unit}, U0 {u0}", fontsize=9)
    return _png(fig)


def luminance_picture(luminance, *, maximum: Optional[float] = None, scale: str = "linear", decades: int = 4,
                      steps: int = 8, contours: bool = False, cmap: str = "turbo", title: Optional[str] = None,
                      units: str = "photometric") -> bytes:
    """A PNG false-colour picture of a luminance image (H, W) in cd/m^2 (radiance in
    W/(m^2 sr) for radiometric `units`). `maximum` defaults to the nice ceiling (1, 2, 2.5,
    5 x 10^k) of the largest finite value; values above it take the top band."""
    from matplotlib import colors

    unit = unit_system(units)["luminance_text"]
    quantity = "luminance" if units == "photometric" else "radiance"

    L = np.asarray(luminance, dtype=np.float64)
    if L.ndim != 2 or L.shape[0] < 1 or L.shape[1] < 1:
        raise StudyError(f"luminance image: expected an (H, W) array in cd/m^2, got shape {L.shape}")
    finite = L[np.isfinite(L)]
    if np.isinf(L).any():
        raise StudyError("luminance image: infinite values")
    if (finite < 0).any():
        raise StudyError(f"luminance image: negative luminance {float(finite.min())} cd/m^2")
    if scale not in ("linear", "log"):
        raise StudyError(f"luminance image: scale {scale!r} (linear or log)")
    if not (isinstance(steps, int) and 2 <= steps <= 64):
        raise StudyError(f"luminance image: steps {steps!r} (an integer 2..64)")
    top = maximum if maximum is not None else nice_ceiling(float(finite.max()) if finite.size else 1.0)
    if not (top > 0 and math.isfinite(top)):
        raise StudyError(f"luminance image: maximum {top!r} cd/m^2 must be positive")
    if scale == "linear":
        bounds = np.linspace(0.0, top, steps + 1)
    else:
        if not (isinstance(decades, int) and decades >= 1):
            raise StudyError(f"luminance image: decades {decades!r} (an integer >= 1)")
        bounds = top * 10.0 ** np.linspace(-decades, 0.0, steps + 1)
    base = __import__("matplotlib").colormaps[cmap].resampled(steps)
    base = base.with_extremes(bad=(0.5, 0.5, 0.5))
    norm = colors.BoundaryNorm(bounds, steps, clip=True)  # above the top: the top band
    h, w = L.shape
    width = 7.0
    fig = _figure(width, max(2.0, width * h / w * 0.85) + 0.6)
    ax = fig.add_subplot(1, 1, 1)
    shown = np.ma.masked_invalid(L)
    im = ax.imshow(shown, cmap=base, norm=norm, interpolation="nearest", origin="upper")
    if contours and h >= 2 and w >= 2:
        ax.contour(np.ma.masked_invalid(L), levels=bounds[1:-1], colors="black", linewidths=0.5, origin="upper")
    ax.set_xticks([])
    ax.set_yticks([])
    cb = fig.colorbar(im, ax=ax, shrink=0.9, ticks=bounds)
    cb.ax.set_yticklabels([f"{b:.3g}" for b in bounds])
    cb.set_label(f"{quantity} ({unit})")
    ax.set_title(title or f"{quantity}, {scale} scale to {top:g} {unit}", fontsize=9)
    return _png(fig)


def camera_luminance(result, camera: Optional[str] = None, *, width: int = 480, height: int = 360,
                     samples: int = 4) -> np.ndarray:
    """The luminance image (height, width) of a bake's camera view: ``result.render(camera,
    width, height, samples)`` (exitant radiance, linear RGB, W/(m^2 sr)) reduced to Y =
    0.2126 R + 0.7152 G + 0.0722 B: cd/m^2 read photometrically. `camera` is a camera prim
    path of the scene, None for the first camera (or hirad's default view)."""
    for name, v, lo in (("width", width, 1), ("height", height, 1), ("samples", samples, 1)):
        if not (isinstance(v, int) and not isinstance(v, bool) and v >= lo):
            raise StudyError(f"luminance image: {name} {v!r} (a positive integer)")
    try:
        rgb = np.asarray(result.render(camera, width, height, samples), dtype=np.float64)
    except Exception as e:  # noqa: BLE001 - a camera that does not exist, an engine error
        from hirad.errors import BakeError

        if isinstance(e, BakeError):
            raise StudyError(f"luminance image: {e}") from None
        raise
    if rgb.shape != (height, width, 3):
        raise StudyError(f"luminance image: the render gave shape {rgb.shape}, expected ({height}, {width}, 3)")
    return rgb @ np.array([0.2126, 0.7152, 0.0722])


def camera_luminance_picture(result, camera: Optional[str] = None, *, width: int = 480, height: int = 360,
                             samples: int = 4, units: str = "photometric", scale: str = "log", decades: int = 3,
                             steps: int = 9, maximum: Optional[float] = None, contours: bool = False,
                             cmap: str = "turbo", title: Optional[str] = None) -> bytes:
    """PNG bytes: the false-colour luminance picture (the counterpart of Radiance's
    ``falsecolor``) of the camera view of a bake's Result (or a stored solution,
    ``hirad.bake.load_solution``), with its legend in cd/m^2 (W/(m^2 sr) when `units` is
    radiometric). Log scale over `decades` decades below `maximum` by default (a room's
    luminances span decades: the emitters and the dark corners); see luminance_picture."""
    unit_system(units)
    lum = camera_luminance(result, camera, width=width, height=height, samples=samples)
    cams = getattr(result, "cameras", None) or []
    where = camera if camera else (cams[0].path if cams else "the default view")
    if title is None:
        q = "luminance" if units == "photometric" else "radiance"
        u = unit_system(units)["luminance_text"]
        finite = lum[np.isfinite(lum)]
        top = maximum if maximum is not None else nice_ceiling(float(finite.max()) if finite.size else 1.0)
        title = f"{q} of {where}, {scale} scale to {top:g} {u}"
    return luminance_picture(lum, maximum=maximum, scale=scale, decades=decades, steps=steps, contours=contours,
                             cmap=cmap, title=title, units=units)


def write_png(path, data: bytes) -> None:
    """Writes PNG bytes atomically."""
    write_bytes(path, data)
