"""Data-driven hypotheses: limbs re-initialised on this frame's landmarks, swapped or not.

The MHT refits every hypothesis from its own previous pose (paper section 2.2). After a
multi-frame left/right swap of the detector, or a limb that moved faster than a few LM steps
follow, every hypothesis starts on the wrong side: the temporal weight W^h then keeps the
right landmarks out (they are far from the previous pose) and the error locks in.

Each frame, :func:`limb_hypotheses` builds S extra starting poses (not in the paper): the
previous output with each arm and leg rotated straight onto this frame's 3D landmarks
(closed-form, :func:`limb_ik`), once with the keypoints as the detector labelled them and
once with the left and right arm and/or leg landmarks exchanged (the detector's commonest
mistake). Each variant is fitted on its own landmarks, relabelled to match, and scored by
Delta (Eq. (3)) with the other hypotheses: the depth image, which a label swap cannot fool,
decides. A variant that loses costs one fit and one render.

Variants (in this order; ``TrackerConfig.limb_hypotheses`` takes the first S):
0. as labelled (re-initialisation: recovers a locked swap and fast limb motion);
1. both arms and both legs exchanged; 2. arms exchanged; 3. legs exchanged.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jaxtyping import Array, Bool, Float, Int

from . import _body as body
from ._camera import Intrinsics
from ._observe import Landmarks
from ._rotation import quat_conjugate, quat_multiply, quat_normalize, quat_to_matrix
from ._select import consensus_set

#: (upper joint frame, lower joint frame, root keypoint, middle keypoint, end keypoint) of the
#: right arm, left arm, right leg, left leg (frames index ``body.JOINT_NAMES``).
LIMBS = ((2, 3, 2, 3, 4), (4, 5, 5, 6, 7), (6, 7, 8, 9, 10), (8, 9, 11, 12, 13))
#: The names of :data:`LIMBS`, in its order (reports, ``summary.json``).
LIMB_NAMES = ("right arm", "left arm", "right leg", "left leg")

_ARMS = (3, 4, 6, 7)  # elbows, wrists
_LEGS = (9, 10, 12, 13)  # knees, ankles


#: Keypoint relabelling of each variant: landmark ``perm[i]`` plays model keypoint i.
VARIANT_PERMUTATIONS = np.stack(
    [body.flip_labels(k) for k in ((), _ARMS + _LEGS, _ARMS, _LEGS)]
).astype(np.int32)
MAX_VARIANTS = len(VARIANT_PERMUTATIONS)


def quat_between(
    a: Float[Array, 3], b: Float[Array, 3], fallback_axis: Float[Array, 3]
) -> Float[Array, 4]:
    """The smallest rotation taking direction ``a`` to ``b`` (wxyz; any lengths > 0).

    For opposite directions the half-way construction degenerates (its norm goes to zero):
    there a half turn about ``fallback_axis`` (made perpendicular to ``a``) is returned.
    """
    a = a / jnp.maximum(jnp.linalg.norm(a), 1e-9)
    b = b / jnp.maximum(jnp.linalg.norm(b), 1e-9)
    q = jnp.concatenate([1.0 + jnp.dot(a, b)[None], jnp.cross(a, b)])
    axis = fallback_axis - jnp.dot(fallback_axis, a) * a
    axis = axis / jnp.maximum(jnp.linalg.norm(axis), 1e-9)
    half_turn = jnp.concatenate([jnp.zeros(1, a.dtype), axis])
    return jnp.where(q[0] > 1e-4, quat_normalize(q), half_turn)


def _rotate(q: Float[Array, 4], v: Float[Array, 3]) -> Float[Array, 3]:
    return quat_to_matrix(q) @ v


def limb_ik(
    shape: body.BodyShape,
    params: Float[Array, 43],
    targets: Float[Array, "kpt 3"],
    valid: Bool[Array, " kpt"],
) -> Float[Array, 43]:
    """``params`` with each limb turned onto target keypoints, in closed form.

    For each arm and leg, the upper joint turns by the smallest rotation that points its bone
    at the target of the middle keypoint (elbow, knee) when that target is ``valid``; then
    the lower joint turns its bone at the end keypoint's target (wrist, ankle) when valid.
    The root, torso and head are untouched; each joint keeps its twist. Quaternions wxyz.

    Args:
        shape: body dimensions.
        params: (43,) the pose to start from.
        targets: (18, 3) target keypoints, metres, camera frame.
        valid: (18,) which targets exist.

    Returns:
        (43,) pose parameters.
    """
    q_local = body.normalize_params(params)[3:].reshape(body.NUM_JOINTS, 4)
    q_root = q_local[0]
    kps = body.keypoints(shape, params)
    down = jnp.asarray([0.0, -1.0, 0.0], params.dtype)
    forward = _rotate(q_root, jnp.asarray([0.0, 0.0, 1.0], params.dtype))
    for upper, lower, k0, k1, k2 in LIMBS:
        # World orientation of the upper joint: root then the joint (its parent is the root).
        Q_up = quat_multiply(q_root, q_local[upper])
        d_cur = _rotate(Q_up, down)
        d_new = targets[k1] - kps[k0]
        turn = quat_between(d_cur, d_new, forward)
        Q_up_new = jnp.where(valid[k1], quat_multiply(turn, Q_up), Q_up)
        q_up_new = quat_multiply(quat_conjugate(q_root), Q_up_new)
        # The middle keypoint where the turned bone puts it, then the lower bone.
        length = jnp.linalg.norm(kps[k1] - kps[k0])
        middle = kps[k0] + length * _rotate(Q_up_new, down)
        Q_low = quat_multiply(Q_up_new, q_local[lower])
        turn2 = quat_between(_rotate(Q_low, down), targets[k2] - middle, forward)
        Q_low_new = jnp.where(valid[k2], quat_multiply(turn2, Q_low), Q_low)
        q_low_new = quat_multiply(quat_conjugate(Q_up_new), Q_low_new)
        q_local = q_local.at[upper].set(q_up_new).at[lower].set(q_low_new)
    return body.normalize_params(jnp.concatenate([params[:3], q_local.reshape(-1)]))


def permute_landmarks(landmarks: Landmarks, perm: Int[Array, " kpt"]) -> Landmarks:
    """The landmarks relabelled: model keypoint i is paired with landmark ``perm[i]``."""
    return jax.tree.map(lambda x: x[perm], landmarks)


def limb_hypotheses(
    shape: body.BodyShape,
    intrinsics: Intrinsics,
    previous: Float[Array, 43],
    landmarks: Landmarks,
    *,
    count: int,
    distance: float | Array,
) -> tuple[Float[Array, "hyp 43"], Landmarks, Bool[Array, "hyp kpt"], Bool[Array, "hyp kpt"]]:
    """The first ``count`` variants (see the module docstring) for this frame.

    Args:
        shape, intrinsics: the body and camera.
        previous: (43,) the previous frame's output pose.
        landmarks: this frame's lifted landmarks.
        count: number of variants, 1..:data:`MAX_VARIANTS` (static).
        distance: a relabelled landmark enters its variant's fit if it lies within this of
            the re-initialised pose's keypoint (metres; 2D: at the keypoint's depth), the
            consensus set as in the tracker's refit.

    Returns:
        ``(starts, landmarks, use3d, use2d)``: (count, 43) starting poses, the relabelled
        landmarks (a leading ``hyp`` axis) and each variant's landmark masks.
    """
    if not 1 <= count <= MAX_VARIANTS:
        raise ValueError(f"limb_hypotheses: count must be in 1..{MAX_VARIANTS}, got {count}")
    perms = jnp.asarray(VARIANT_PERMUTATIONS[:count])

    def one(perm):
        lm = permute_landmarks(landmarks, perm)
        start = limb_ik(shape, previous, lm.points3d, lm.has_depth)
        use3d, use2d = consensus_set(lm, body.keypoints(shape, start), intrinsics, distance)
        return start, lm, use3d, use2d

    return jax.vmap(one)(perms)
