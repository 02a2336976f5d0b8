"""Inverse design: recover a lathe's profile from rendered images.

The target images are renders of a hidden profile from several views; the
optimisation starts from a cylinder with as many points, renders the same
views with ``lathe_prb`` (profile gradients, outline included), and moves
the points with Adam on the image loss plus two regularisers (smoothness,
and even spacing along the chain), optionally coarse to fine. After
every step the points are projected back onto valid profiles: the ends of
an axis-ended chain stay on the axis, radii stay positive, heights stay
ordered (a z-monotone chain closed along the axis cannot cross itself), and
an update that the profile validation still refuses is undone with a
smaller step.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import drjit as dr
import mitsuba as mi
import numpy as np

from ..profiles import ProfileError
from ..profiles import bspline as bs
from .diff_scenes import lathe_scene
from .gradients import points_key

__all__ = ["HIDDEN_PROFILES", "InverseResult", "Stage", "cylinder_like", "plot_convergence", "plot_losses",
           "profile_curve", "profile_rms_error", "project_profile", "recover_profile", "render_views",
           "write_result_images"]

#: The hidden profiles of the examples and tests: a 12-point polyline glass
#: (foot, waist, bowl, bevelled rim) and an 8-control-point B-spline vase
#: (both axis-ended, bottom first).
HIDDEN_PROFILES = {
    "polyline": np.array([(0.0, 0.0), (0.5, 0.0), (0.55, 0.1), (0.45, 0.3), (0.3, 0.45), (0.25, 0.6),
                          (0.35, 0.75), (0.55, 0.9), (0.65, 1.05), (0.62, 1.15), (0.5, 1.2), (0.0, 1.2)]),
    "bspline": np.array([(0.0, 0.0), (0.5, 0.0), (0.7, 0.3), (0.4, 0.6), (0.35, 0.85), (0.55, 1.1),
                         (0.45, 1.2), (0.0, 1.2)]),
}

#: Two views: from just above the rim at one side (low enough that a top
#: cap bulging into a cone shows in the outline, high enough to see the cap),
#: and from below at the other (the bottom of a vase is seen by no view from
#: above).
INVERSE_VIEWS = ((10.0, 1.6), (100.0, -0.6))

#: Lights on opposite sides, above and below, so that every part of the
#: outline is lit.
INVERSE_LIGHTS = ((2.0, -2.0, 3.0), (-2.0, 2.0, -1.5))


def cylinder_like(points: np.ndarray) -> np.ndarray:
    """A cylinder with as many points as the axis-ended chain ``points``
    (bottom and top on the axis), over the chain's z range with 0.7 times
    its widest radius: the axis ends and the two rim corners, and the other
    points spread over the bottom cap, the wall and the top cap in
    proportion to their lengths (points on the caps let the optimisation
    shape a rim or a foot)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    z_lo, z_hi = points[:, 1].min(), points[:, 1].max()
    radius = 0.7 * points[:, 0].max()
    free = len(points) - 4
    lengths = np.array([radius, z_hi - z_lo, radius])
    counts = np.floor(free * lengths / lengths.sum()).astype(int)
    counts[1] += free - counts.sum()

    def inner(a, b, count):
        return [a + (b - a) * (k + 1) / (count + 1) for k in range(count)]

    corners = [np.array(p) for p in ((0.0, z_lo), (radius, z_lo), (radius, z_hi), (0.0, z_hi))]
    chain = [corners[0]]
    for k in range(3):
        chain += inner(corners[k], corners[k + 1], counts[k]) + [corners[k + 1]]
    return np.array(chain)


def project_profile(points: np.ndarray, min_radius: float) -> np.ndarray:
    """The nearest z-monotone axis-ended chain: ends on the axis, interior
    radii at least ``min_radius``, heights non-decreasing."""
    p = np.array(points, dtype=np.float64).reshape(-1, 2)
    p[[0, -1], 0] = 0.0
    p[1:-1, 0] = np.maximum(p[1:-1, 0], min_radius)
    p[:, 1] = np.maximum.accumulate(p[:, 1])
    return p


def profile_curve(points: np.ndarray, kind: str, samples: int = 400) -> np.ndarray:
    """(m, 2) points densely along the profile curve (a polyline's chain, a
    B-spline's open curve)."""
    points = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if kind == "bspline":
        controls = bs.bspline_segments(points, "profile_curve")
        t = np.linspace(0.0, len(controls), samples, endpoint=False)
        index = np.minimum(t.astype(int), len(controls) - 1)
        r, z = bs.evaluate(controls, index, t - index)
        return np.stack([r, z], axis=1)
    lengths = np.linalg.norm(np.diff(points, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(lengths)])
    t = np.linspace(0.0, s[-1], samples)
    return np.stack([np.interp(t, s, points[:, 0]), np.interp(t, s, points[:, 1])], axis=1)


def _distance_to_chain(samples: np.ndarray, chain: np.ndarray) -> np.ndarray:
    """Distance of every sample to the polyline ``chain``."""
    a, b = chain[:-1], chain[1:]
    ab = b - a
    t = np.einsum("ijk,jk->ij", samples[:, None, :] - a[None], ab) / np.maximum(np.einsum("jk,jk->j", ab, ab),
                                                                               1e-300)
    closest = a[None] + np.clip(t, 0.0, 1.0)[..., None] * ab[None]
    return np.linalg.norm(samples[:, None, :] - closest, axis=2).min(axis=1)


def profile_rms_error(points: np.ndarray, target: np.ndarray, kind: str) -> float:
    """Symmetric RMS distance between the two profile curves, relative to
    the target's height."""
    a, b = profile_curve(points, kind), profile_curve(target, kind)
    d = np.concatenate([_distance_to_chain(a, b), _distance_to_chain(b, a)])
    height = float(np.ptp(b[:, 1]))
    return float(np.sqrt(np.mean(d * d)) / height)


def _smoothness(points: mi.Float) -> mi.Float:
    """Sum of squared second differences of the points (r and z)."""
    n = dr.width(points) // 2
    index = dr.arange(mi.UInt32, n - 2)  # the interior points, less one

    def coordinate(offset, k):
        return dr.gather(mi.Float, points, 2 * (index + offset) + k)

    total = mi.Float(0.0)
    for k in range(2):
        second = coordinate(0, k) - 2 * coordinate(1, k) + coordinate(2, k)
        total += dr.sum(second * second)
    return total


def _spacing(points: mi.Float) -> mi.Float:
    """Sum of squared offsets of the interior points from their neighbours'
    midpoint, along the neighbours' chord (detached): uneven spacing along
    the chain, with no pull on its shape (the image loss has no gradient
    for a point sliding along a straight run)."""
    n = dr.width(points) // 2
    index = dr.arange(mi.UInt32, n - 2)

    def point(offset):
        return mi.Point2f(*(dr.gather(mi.Float, points, 2 * (index + offset) + k) for k in range(2)))

    before, here, after = point(0), point(1), point(2)
    chord = dr.detach(after - before)
    along = dr.dot(chord, here - dr.detach(0.5 * (before + after))) / dr.maximum(dr.norm(chord), 1e-6)
    return dr.sum(dr.square(along))


def render_views(scene: mi.Scene, spp: int, seed: int = 0, params=None) -> list[mi.TensorXf]:
    """One render per sensor of ``scene``."""
    return [mi.render(scene, params, sensor=k, spp=spp, seed=seed + 1000 * k, seed_grad=seed + 1000 * k + 1)
            for k in range(len(scene.sensors()))]


@dataclass
class InverseResult:
    """The recovered points, per-iteration loss and profile error, and the
    images of the start and of the end."""

    points: np.ndarray
    losses: list[float] = field(default_factory=list)
    errors: list[float] = field(default_factory=list)
    before: list[np.ndarray] = field(default_factory=list)
    after: list[np.ndarray] = field(default_factory=list)
    targets: list[np.ndarray] = field(default_factory=list)


def _scalar(loss: mi.Float) -> float:
    """A one-entry (loss) array's value, detached from AD."""
    return float(np.array(dr.detach(loss)).ravel()[0])


def _write_points(params, key: str, points: np.ndarray) -> bool:
    """Set the points (re-validated); False when the profile is refused."""
    try:
        params[key] = mi.Float(points.ravel().astype(np.float32))
        params.update()
    except ProfileError:
        return False
    return True


@dataclass(frozen=True)
class Stage:
    """One stage of a coarse-to-fine schedule: ``iterations`` Adam steps on
    renders of ``resolution`` x ``resolution`` pixels, the step size
    decaying tenfold from ``learning_rate``."""

    resolution: int
    iterations: int
    learning_rate: float


def _step_points(params, key: str, current: np.ndarray, proposal: np.ndarray) -> np.ndarray:
    """Move from ``current`` towards ``proposal``, halving the step while
    the profile validation refuses it; the points written."""
    step = 1.0
    while not _write_points(params, key, current + step * (proposal - current)) and step > 1e-3:
        step *= 0.5
    return np.array(params[key], dtype=np.float64).reshape(-1, 2)


def _image_loss(images, targets) -> mi.Float:
    """Mean squared pixel difference, summed over the views."""
    loss = mi.Float(0.0)
    for image, reference_image in zip(images, targets, strict=True):
        loss += dr.mean(dr.square(image - reference_image), axis=None)
    return loss


def recover_profile(target: np.ndarray, kind: str = "polyline", iterations: int = 60, resolution: int = 32,
                    spp: int = 8, learning_rate: float = 0.02, smoothness: float = 3e-3,
                    spacing: float = 3e-3, views: tuple[tuple[float, float], ...] = INVERSE_VIEWS,
                    report: Callable[[int, float, float], None] | None = None,
                    stages: tuple[Stage, ...] | None = None, seed: int = 0) -> InverseResult:
    """Recover the axis-ended profile ``target`` ((n, 2) points of ``kind``)
    from renders of it in ``views`` (pixel samples of ``seed``), starting
    from :func:`cylinder_like`. ``stages`` (coarse to fine) replaces the one
    stage ``(resolution, iterations, learning_rate)``. The weights of the
    regularisers (:func:`_smoothness`, :func:`_spacing`) decay hundredfold
    over a stage: they keep the points evenly spread while they travel far,
    then fade so as not to round the profile's corners. ``report(iteration,
    loss, profile_error)`` is called every iteration."""
    target = np.asarray(target, dtype=np.float64).reshape(-1, 2)
    stages = stages or (Stage(resolution, iterations, learning_rate),)
    current = cylinder_like(target)
    result = InverseResult(current)
    min_radius = 0.02 * float(np.ptp(target[:, 1]))
    optimizer = mi.ad.Adam(lr=stages[0].learning_rate)
    optimizer["points"] = mi.Float(current.ravel().astype(np.float32))
    from ..plugin.shape import scene_lathes  # needs a variant

    for stage in stages:
        reference = lathe_scene(target, kind, stage.resolution, views, reference="proxy",
                                lights=INVERSE_LIGHTS)
        # The same seed for the targets and every render of the optimisation:
        # the pixel samples are then the same, and at the hidden profile the
        # loss is exactly zero instead of a floor of sampling noise
        targets = render_views(reference, spp, seed)
        scene = lathe_scene(current, kind, stage.resolution, views, reference="proxy", lights=INVERSE_LIGHTS)
        params = mi.traverse(scene)
        key = points_key(params, scene_lathes(scene)[0])
        if not result.before:
            result.before = [np.array(image) for image in render_views(scene, spp, seed)]
        for iteration in range(stage.iterations):
            # Step sizes decay tenfold over the stage: large moves first,
            # then sub-pixel refinement
            decay = 0.1 ** (iteration / max(stage.iterations - 1, 1))
            optimizer.set_learning_rate(stage.learning_rate * decay)
            params[key] = optimizer["points"]
            params.update()
            loss = decay ** 2 * (smoothness * _smoothness(optimizer["points"])
                                 + spacing * _spacing(optimizer["points"]))
            loss += _image_loss(render_views(scene, spp, seed, params), targets)
            dr.backward(loss)
            optimizer.step()
            proposal = project_profile(np.array(optimizer["points"]), min_radius)
            current = _step_points(params, key, current, proposal)
            optimizer["points"] = mi.Float(current.ravel().astype(np.float32))
            result.losses.append(_scalar(loss))
            result.errors.append(profile_rms_error(current, target, kind))
            if report is not None:
                report(len(result.losses) - 1, result.losses[-1], result.errors[-1])
    result.points = current
    result.targets = [np.array(image) for image in targets]
    result.after = [np.array(image) for image in render_views(scene, spp, seed)]
    return result


def plot_convergence(result: InverseResult, path: str, title: str = "") -> None:
    """Loss and profile error per iteration (log scale) as a PNG."""
    plot_losses(result.losses, {"profile RMS error / height": result.errors}, path, title)


def plot_losses(losses: list[float], errors: dict[str, list[float]], path: str, title: str = "",
                mark: tuple[int, str] | None = None) -> None:
    """The image loss and each named error series per iteration (log
    scale), with the 1% line, as a PNG; ``mark`` (iteration, label): a
    vertical line there."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(5.5, 3.6))
    ax.semilogy(losses, label="image loss")
    for label, series in errors.items():
        ax.semilogy(series, label=label)
    ax.axhline(0.01, color="gray", lw=0.8, ls="--", label="1% of height")
    if mark is not None:
        ax.axvline(mark[0], color="black", lw=0.8, ls=":", label=mark[1])
    ax.set_xlabel("iteration")
    ax.set_title(title, fontsize=9)
    ax.grid(True, which="both", alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def write_result_images(result: InverseResult, directory: str) -> list[str]:
    """``view_K_{target,before,after}.png`` for every view; the paths."""
    import os

    from .images import write_png

    paths = []
    for k, images in enumerate(zip(result.targets, result.before, result.after, strict=True)):
        for name, image in zip(("target", "before", "after"), images, strict=True):
            paths.append(os.path.join(directory, f"view_{k}_{name}.png"))
            write_png(paths[-1], np.asarray(image)[..., :3])
    return paths
