"""Frames in chunks: the tracker step over C frames as one ``lax.scan`` (one call, one wait).

:meth:`Tracker.run <posetrack.Tracker.run>` used to call the step once per frame and wait for
it, because the host decides from each frame's result whether the track holds, is lost or is
dropped. Those per-frame decisions are a few comparisons; they run here, inside the scan,
exactly as :meth:`Tracker.update <posetrack.Tracker.update>` makes them on the host:

- fewer than ``min_landmarks`` landmarks with depth: *no observation*, the hypotheses are held;
- Delta above ``lost_delta`` or agreement below ``lost_agreement``: *lost* (the new hypotheses
  are kept), and after ``lost_patience`` lost frames in a row the track is *dropped*;
- otherwise *tracked* (the lost count restarts).

A frame whose followed person was not found (only other people in view) runs no step and
counts as lost. Once the track is dropped the chunk's later frames are not run: the host
re-initialises and starts the next chunk there. Everything the host chooses before a step
(the followed person, the left/right labelling, other people's pixels removed) depends on no
step's result while the track lives, so the host prepares a chunk's frames ahead.

The thresholds are compared in float32 on the device but mean what the host's float64
comparisons mean (:func:`status_limits`), and the step inside the scan gives the same poses as
the per-frame program, bit for bit (``tests/test_chunk.py``).
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from ._config import TrackerConfig
from ._programs import program
from ._step import LOST, NO_OBSERVATION, TRACKED, FrameEstimate, TrackState, tracker_step


class ChunkFrames(eqx.Module):
    """Per frame of a chunk (leading axis C); rows after a drop are not meaningful."""

    estimate: FrameEstimate
    """The step's estimate (zeros where no step ran)."""
    status: Int[Array, " C"]
    """:data:`TRACKED`, :data:`LOST` or :data:`NO_OBSERVATION`."""
    ran: Bool[Array, " C"]
    """The frame was processed: the track was alive when it came (False after a drop)."""
    dropped: Bool[Array, " C"]
    """The track was dropped at this frame (``lost_patience`` lost frames in a row)."""
    held: Float[Array, "C 43"]
    """The track's pose after the frame (its ``best``): the held one where nothing was
    observed."""


def status_limits(config: TrackerConfig) -> np.ndarray:
    """``(lost_delta, lost_agreement)`` as float32 thresholds with the host's meaning.

    The host tests ``float(delta) > lost_delta`` and ``float(agreement) < lost_agreement`` in
    float64 on float32 values. For a float32 ``d`` and a real ``L``, ``d > L`` exactly when
    ``d > L_down`` (``L_down``: the largest float32 <= L), and ``a < A`` exactly when
    ``a < A_up`` (the smallest float32 >= A); a plain float32 cast would round either way.
    """
    d, a = float(config.lost_delta), float(config.lost_agreement)
    d32, a32 = np.float32(d), np.float32(a)
    if float(d32) > d:
        d32 = np.nextafter(d32, np.float32(-np.inf))
    if float(a32) < a:
        a32 = np.nextafter(a32, np.float32(np.inf))
    return np.array([d32, a32], np.float32)


def track_chunk(
    config: TrackerConfig,
    shape,
    intrinsics,
    floor,
    state: TrackState,
    lost_run: Int[Array, ""],
    limits: Float[Array, "2"],
    run: Bool[Array, " C"],
    lost_only: Bool[Array, " C"],
    depth: Float[Array, "C H W"],
    kp2d: Float[Array, "C 18 2"],
    conf: Float[Array, "C 18"],
) -> tuple[tuple[TrackState, Int[Array, ""]], ChunkFrames]:
    """:func:`~posetrack.tracker_step` over C frames with :class:`~posetrack.Tracker`'s
    per-frame status logic (module docstring).

    Args:
        config, shape, intrinsics, floor, state: as for ``tracker_step``; ``state`` is the
            live track's.
        lost_run: lost frames in a row before the chunk.
        limits: :func:`status_limits` of ``config``.
        run: per frame, whether it runs the step (False: padding, or no followed person).
        lost_only: per frame without a step, whether it counts as lost (other people in view).
        depth, kp2d, conf: per frame, the step's inputs (depth in metres, as fitted).

    Returns:
        ``((state, lost_run) after the chunk, per-frame ChunkFrames)``; after a drop the state
        is the one the host drops.
    """

    def frame(carry, x):
        st, lost, alive = carry
        go, lost_no_step, d, k, c = x
        step = alive & go

        def fit(s):
            return _jitted_step(config, shape, intrinsics, floor, s, d, k, c)

        def skip(s):
            # The outputs' structure, from the trace ``fit`` just made (jit caches it): the
            # step is traced once, not once per branch (2.7 s more on a cold start).
            return jax.tree.map(
                lambda a: jnp.zeros(a.shape, a.dtype), jax.eval_shape(fit, s)
            )  # fmt: skip

        new, est = jax.lax.cond(step, fit, skip, st)
        unobserved = est.num_3d < config.min_landmarks
        far = (est.delta > limits[0]) | (est.agreement < limits[1])
        status = jnp.where(
            step,
            jnp.where(unobserved, NO_OBSERVATION, jnp.where(far, LOST, TRACKED)),
            jnp.where(lost_no_step, LOST, NO_OBSERVATION),
        )
        keep = step & ~unobserved
        new = eqx.tree_at(lambda t: t.trusted, new, ~far)  # the state carries the verdict
        st = jax.tree.map(lambda a, b: jnp.where(keep, a, b), new, st)
        lost = jnp.where(status == LOST, lost + 1, jnp.where(status == TRACKED, 0, lost))
        dropped = alive & (status == LOST) & (lost >= config.lost_patience)
        lost = jnp.where(dropped, 0, lost)
        out = ChunkFrames(estimate=est, status=status, ran=alive, dropped=dropped, held=st.best)
        return (st, lost, alive & ~dropped), out

    (state, lost_run, _), frames = jax.lax.scan(
        frame, (state, jnp.asarray(lost_run, jnp.int32), jnp.asarray(True)),
        (run, lost_only, depth, kp2d, conf),
    )  # fmt: skip
    return (state, lost_run), frames


_jitted_step = jax.jit(tracker_step)


#: :func:`track_chunk`, compiled (once per configuration, image size and chunk length).
step_chunk = program("step_chunk")(track_chunk)
