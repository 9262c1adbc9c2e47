"""Work budgets: typical rates, the default ray limit, and refusals that say how long work would take.

Ambient occlusion (:func:`ao4d.ambient_occlusion`), rendering (:func:`ao4d.render`), screen AO
and the command line's extraction estimate their work before they start and refuse what would
run longer than about half an hour at these rates, naming the option that lifts the limit.
"""

from __future__ import annotations

from ._validate import as_real

__all__ = ["RAYS_PER_SECOND", "MAX_RAYS", "duration", "check_rays"]

# Typical rates (rays/s) on this project's 2-core machine, for estimates before long work; a
# GPU is faster, which only makes the estimate cautious.
RAYS_PER_SECOND = {"opencl": 8e6, "numpy": 7e4}
# Refuse more rays than this by default: about half an hour at the typical rate.
MAX_RAYS = {backend: 1800 * rate for backend, rate in RAYS_PER_SECOND.items()}


def duration(seconds: float) -> str:
    """A rough duration for estimates ("about 40 s", "about 3 h", "about 12 days")."""
    for unit, size in (("days", 86400), ("h", 3600), ("min", 60)):
        if seconds >= 2 * size:
            return f"about {seconds / size:.0f} {unit}"
    return f"about {max(seconds, 1):.0f} s"


def check_rays(n_rays: float, backend: str, limit: float | None, *, what: str, hint: str) -> None:
    """Refuse, before any work, to trace more than ``limit`` rays (default ``MAX_RAYS[backend]``)."""
    limit = MAX_RAYS[backend] if limit is None else as_real(limit, "max_rays", finite=False, gt=0)
    if n_rays > limit:
        raise ValueError(
            f"{what} asks for {n_rays:.3g} rays, {duration(n_rays / RAYS_PER_SECOND[backend])} on the "
            f"{backend} backend at ~{RAYS_PER_SECOND[backend]:.2g} rays/s, above the limit of "
            f"{limit:.3g} rays; {hint}"
        )
