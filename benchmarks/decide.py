"""Tuning-seed decision runs (issue 12): D of tracker variants per clip and tracker seed.

Variants differ in one setting: the filter of detections that jumped onto another keypoint
(``DuplicateSettings``), the left/right groups relabelled (``SideSettings.groups``), the
consensus refit or the lifting's depth band (``TrackerConfig``).

Runs the 40 tuning clips of the decisions recorded in benchmarks/README.md (wide real motion
seeds 150-157 with ``tune.REAL``, wide procedural 144-149 and standard 136-141 with
``tune.PROCEDURAL`` in order; occlusion 0 and 2; 120 frames at 30 fps, 320x240), each with
the tracker seeds given, and appends one JSON line per clip and seed: D (mm, body joints),
coverage, swapped-limb frames, acceleration error and the detections dropped, per variant,
with the step's median ms a frame and, online, the motion model's (timed in the run: two
processes on two cores inflate both, the small motion-model programs far more).
Tuning seeds only: never point it at ``REPORT_SEEDS``.

    python benchmarks/decide.py OUT.jsonl --variants kept,settle1 --mode offline
    python benchmarks/decide.py OUT.jsonl --variants sides:arms+legs,sides:arms+legs+torso
    python benchmarks/decide.py OUT.jsonl --part 0 --parts 2 ...  # two processes
    python benchmarks/decide.py OUT.jsonl --real-seeds 100-123 ...  # other tuning clips
    python benchmarks/decide.py OUT.jsonl --real-seeds 176,178 --standard-seeds 168-170 \
        --procedural-seeds 171-173 --side-seeds 196,197 --tracker-seeds 0,1,2 ...
    python benchmarks/decide.py OUT.jsonl --mode per-frame --variants default,alllm,lvm
    python benchmarks/decide.py OUT.jsonl --cmu-late-seeds 1346-1351 --no-base ...

CMU motion (``--cmu-late-seeds``): the report sets' real-motion clips include the shared
data's three CMU recordings (subject 131), from their start (``motion_start`` 0: the first
4 s at 30 fps), and ``tune.REAL`` has no clip of that kind. The ``cmu late`` group tracks the
same three recordings from :data:`CMU_LATE_START` on (4.2 s: after every frame a report clip
shows), so a change can be tried on that kind of motion without looking at a report clip. It
is the same person, session and style as the report clips (the stretches do not overlap, the
motion does in kind): read a result there as a tuning hint, not as independent evidence.

Variants: ``default`` (every setting the mode's default), ``inbatch``
(``TrackerConfig(consensus_in_batch=True)``), ``norefit`` (``consensus_refit=False``),
``alllm`` (``TrackerConfig(all_landmarks_hypothesis=True)``), ``far2d``
(``TrackerConfig(far_side_2d=True)``), ``farbound`` (``TrackerConfig(far_side_bound=True)``),
``farboundS`` (the same with ``bound_turn_sin=S``; both ungated, ``bound_trusted=False``, in
every mode), ``farboundT`` (the bound only while the previous output passed the track-loss
test: ``bound_trusted=True``; online the default since 2026-12-07), ``nobound``
(``far_side_bound=False``: online, the default before 2026-12-07), ``farboundT-axesN`` (that
with ``axesN``), ``axesN``
(``reinit_partial_frames=N`` with ``reinit_partial_axes=True``: a restart without a
left/right pair from the last tracked pose's facing only),
``alllm-norefit`` (that and no
consensus refit), ``lvm`` (``TrackerConfig.recommended("lvm")``), ``lvm-trackedN`` (that
with ``reinit_check_tracked=N``), ``oaccX``
(``SmoothSettings(online_accel_std=X)``, m/s^2), ``orobustX``
(``SmoothSettings(online_robust=X)``, metres; 0.05 is the default since 2026-12-08, so
``orobust0`` is the online smoothing before it), ``owinN`` (``SmoothSettings(online_window=N)``:
the online smoothing over the newest N frames; 12 is the default), ``anchorX``
(``SideSettings.for_mode("online", online_anchor=X)``, metres; online only), ``amargX``
(``SideSettings.for_mode("online", arbitrate_margin=X)``; groups as online), ``oframesN``
(``SideSettings.for_mode("online", online_frames=N)``), ``omodelX``
(``SideSettings.for_mode("online", online_model=X)``, metres; 0 = off), ``legcrossW``
(``ResidualSettings(leg_cross=W)`` in the fits and the offline smoother; ``legcrossW-free``: and
``leg_labels_free=True``; ``legcrossW-freeside``: label-free in side views only,
``leg_labels_free_sin=posetrack._visibility.SIDE_VIEW_SIN``; ``legcrossW-freeM``: label-free with
``leg_labels_margin=M``, a pair exchanged only where M times cheaper; a ``-nK`` tail:
``leg_terms_min=K``, the leg terms on frames with K landmarks on depth or more), ``smoothlegW`` /
``smoothlegW-free`` (the same in the motion model's residuals only:
``SmoothSettings.residuals``), ``bothways``
(``SmoothSettings(both_ways=True)``: offline, the recording tracked forwards and backwards
and the two passes averaged), ``crossfade`` (``SmoothSettings(crossfade=True)``: the
offline windows blended over their shared frames; the default since 2026-12-02, so the same
as ``default`` now), ``bothways-crossfade`` (both; the same as ``bothways`` now), ``kept``
(``duplicates=None``), ``settleN``
(``DuplicateSettings(settle=N)``; ``settle1`` is the default filter), ``bandM``
(``TrackerConfig(lift_band=M)``, metres), ``agreeX`` (``TrackerConfig(lost_agreement=X)``),
``followX`` (``FollowSettings(depth_band=X)``, metres), ``spreadN`` (online: each
body-shape refinement spread over N updates, ``ShapeFitSettings.online_spread=N``),
``aloneN`` (the mode's ``FollowSettings`` with ``alone_frames=N``), ``grouparb``
(``SideSettings.for_mode(mode, arbitrate_groups=True)``), ``ogroups``
(``SideSettings.for_mode(mode, online_groups=True)``), ``checkfit``
(``TrackerConfig(reinit_check_fit=True)``), ``checkfitN`` (the same with
``reinit_check_frames=N``: the check looks N frames after a loss), ``trackedN``
(``TrackerConfig(reinit_check_tracked=N)``: the fit checked against the last tracked pose;
the default is 25 since 2026-12-06, so ``tracked0`` is the old restart), ``cdeltaN``
(``TrackerConfig(reinit_check_delta=N/1000)``: the check's exchange kept only if its Delta is
at most the plain fit's + N/1000),
``confX`` (``TrackerConfig(depth_confidence=X)``),
``farX`` (the same on the far side's limbs in a side view only,
``TrackerConfig(depth_confidence_far=X)``), ``turnsX`` (the mode's ``SideSettings`` with
``frontal_turns=X``), ``sides:G+G...`` (``SideSettings(groups=(G,
...))``, names from ``posetrack.SIDE_GROUPS``; a ``/with-limbs`` suffix sets
``torso_with_limbs``), ``priorS/M`` (the body-shape refinement,
``ShapeFitSettings.tracking(mode)``, with ``prior_sigma=S`` and ``max_change=M``), ``rpriorS/M``
(the same with ``radius_prior_sigma=S``: the part radii only), ``girthS`` (the same with
``girth_prior_sigma=S``: the radii's common factor only, their ratios held), ``twopassS``
(offline: the recording tracked twice, the second time from the first's refined shape, both
refinements with ``radius_prior_sigma=S``; the time is both passes'), ``prepassN`` (offline:
the first N frames tracked alone first, their refined shape (``radius_prior_sigma`` 10: the
radii's prior off) the start of the whole recording's tracking, refined the same way:
``ShapeFitSettings.offline_first``; the time is both; ``prepassNr``: the same with only the
part radii refined, the lengths as measured; ``prepassNg``: the same with the mode's own
refinement settings, offline the girth prior), ``gateX`` (offline: ``prepass40g`` only where
the first 40 frames' observed keypoint share is below X: ``offline_first_below``; the default
elsewhere); every other setting is the mode's default.
~25-40 s per run on 2 CPU cores.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import time
from pathlib import Path

import numpy as np
from accuracy import REAL as REPORTED_REAL  # the reported real clips (CMU: the late group)
from parts import add_part_arguments, check_part, share
from seeds import TUNING_SEEDS, parse_seeds
from tune import PROCEDURAL, REAL, check_seeds, decision_measures, real_motion, shared_measures

import posetrack as pt
from posetrack._visibility import SIDE_VIEW_SIN


def clips(
    real_seeds: list[int] | None = None,
    side_seeds: list[int] | None = None,
    base: bool = True,
    procedural_seeds: list[int] | None = None,
    standard_seeds: list[int] | None = None,
    cmu_late_seeds: list[int] | None = None,
) -> list[tuple[str, int, str, str]]:
    """``(group, seed, motion, variety)`` of the 20 decision clips (each at 2 occlusions).

    Given any of ``real_seeds`` (wide real motion clips, :func:`tune.real_motion`, as
    ``losses.py --kind real``), ``procedural_seeds`` (wide procedural clips) or
    ``standard_seeds`` (standard procedural clips; both of motion ``PROCEDURAL[seed % 6]``),
    the clips of those tuning seeds instead, in that order; ``side_seeds`` adds wide
    procedural ``walk_across`` clips of those tuning seeds (a side view walking across the
    room and turning round, a motion the 40 clips do not have); ``base=False``: not the 20
    decision clips (the seeds given only); ``cmu_late_seeds`` adds :func:`cmu_late` clips."""
    own = {
        "--real-seeds": real_seeds,
        "--procedural-seeds": procedural_seeds,
        "--standard-seeds": standard_seeds,
    }
    for option, seeds in own.items():
        if seeds is not None:
            _check(seeds, option)
    if all(seeds is None for seeds in own.values()):
        out = _base_clips() if base else []
    else:
        out = [("wide real", s, real_motion(s), "wide") for s in real_seeds or ()]
        for group, variety, seeds in (
            ("wide procedural", "wide", procedural_seeds),
            ("standard", "standard", standard_seeds),
        ):
            out += [(group, s, PROCEDURAL[s % len(PROCEDURAL)], variety) for s in seeds or ()]
    if side_seeds is not None:
        _check(side_seeds, "--side-seeds")
        out += [("walk_across", s, "walk_across", "wide") for s in side_seeds]
    if cmu_late_seeds is not None:
        _check(cmu_late_seeds, "--cmu-late-seeds")
        out += [cmu_late(s) for s in cmu_late_seeds]
    return out


#: The report sets' CMU recordings (the shared data's subject 131), read from ``accuracy.REAL``.
CMU = tuple(m for m in REPORTED_REAL if m.startswith("cmu:"))
#: Where the ``cmu late`` clips start in their recording, s: after the last frame a report
#: clip shows (120 frames at 30 fps from 0 s: up to 3.97 s); 131_01, the shortest (8.28 s),
#: still holds 120 frames from here without playing back.
CMU_LATE_START = 4.2


def cmu_late(seed: int) -> tuple[str, int, str, str]:
    """The ``cmu late`` clip of a tuning seed: recording ``CMU[seed % 3]`` from
    :data:`CMU_LATE_START` (the motion ``"cmu:131_0N@4.2"``, :func:`split_start`), on the
    wide body for even seeds and the standard one for odd (six seeds in a row cover every
    recording on both bodies, as the report sets' ``real`` and ``real-wide``)."""
    motion = f"{CMU[seed % len(CMU)]}@{CMU_LATE_START}"
    return "cmu late", seed, motion, ("wide", "standard")[seed % 2]


def split_start(motion: str) -> tuple[str, float]:
    """``(motion, motion_start)`` of a clip's motion name: ``"cmu:131_01@4.2"`` is
    ``cmu:131_01`` from 4.2 s; a name without ``@`` starts at 0."""
    name, at, start = motion.partition("@")
    return name, float(start) if at else 0.0


def generate_clip(
    seed: int, motion: str, variety: str, occlusion: int
) -> pt.synth.SyntheticSequence:
    """A decision clip's recording: ``motion`` (``"name"`` or ``"name@start"``, see
    :func:`split_start`) of a tuning seed, 120 frames at 30 fps, 320x240, no RGB."""
    recording, start = split_start(motion)
    return pt.synth.generate(
        seed, motion=recording, n_frames=120, fps=30.0, occlusion_level=occlusion, width=320,
        height=240, with_rgb=False, variety=variety, motion_start=start,
    )  # fmt: skip


def _check(seeds: list[int], option: str) -> None:
    try:
        check_seeds(seeds)
    except ValueError as e:
        raise SystemExit(f"error: {option}: {e}") from None


def _base_clips() -> list[tuple[str, int, str, str]]:
    out = [("wide real", s, REAL[i % len(REAL)], "wide") for i, s in enumerate(range(150, 158))]
    out += [("wide procedural", s, PROCEDURAL[i], "wide") for i, s in enumerate(range(144, 150))]
    out += [("standard", s, PROCEDURAL[i], "standard") for i, s in enumerate(range(136, 142))]
    assert all(c[1] in TUNING_SEEDS for c in out)
    return out


#: Variants of one online left/right setting (``SideSettings.for_mode("online", ...)``): name
#: prefix -> (field, type of the number that follows).
_ONLINE_SIDES = {
    "anchor": ("online_anchor", float),
    "amarg": ("arbitrate_margin", float),
    "oframes": ("online_frames", int),
    "omodel": ("online_model", float),
}


#: Variants of one numeric setting: name prefix -> (``Tracker`` keyword, settings class,
#: field, type of the number that follows the prefix).
_NUMBERED = {
    "oacc": ("motion", pt.SmoothSettings, "online_accel_std", float),
    "orobust": ("motion", pt.SmoothSettings, "online_robust", float),
    "owin": ("motion", pt.SmoothSettings, "online_window", int),
    "conf": ("config", pt.TrackerConfig, "depth_confidence", float),
    "far": ("config", pt.TrackerConfig, "depth_confidence_far", float),
    "band": ("config", pt.TrackerConfig, "lift_band", float),
    "agree": ("config", pt.TrackerConfig, "lost_agreement", float),
    "follow": ("follow", pt.FollowSettings, "depth_band", float),
}


def _leg_terms(variant: str, prefix: str, residuals, allowed: tuple[str, ...]):
    """``residuals`` with a ``PREFIXW[-free|-freeM|-freeside][-nK]`` variant's leg terms: the
    limit on crossed legs at weight W, label-free legs (``-free``; ``-freeM``: a pair exchanged
    only where M times cheaper than as labelled), in side views only (``-freeside``); both only
    on frames with at least K landmarks on depth (``-nK``)."""
    rest, _, fewest = variant[len(prefix) :].partition("-n")  # -nK: K landmarks or more
    weight, _, free = rest.partition("-")
    margin = free.removeprefix("free") if free.startswith("free") else ""
    if margin and margin != "side":
        free = "free"
    try:
        if free not in allowed:
            raise ValueError("expected " + " or ".join(f"{prefix}W" + (f"-{a}" if a else "")
                                                       for a in allowed))  # fmt: skip
        return dataclasses.replace(
            residuals, leg_cross=float(weight), leg_labels_free=free != "",
            leg_labels_free_sin=SIDE_VIEW_SIN if free == "freeside" else 0.0,
            leg_labels_margin=float(margin) if free == "free" and margin else 1.0,
            leg_terms_min=int(fewest or 0),
        )  # fmt: skip
    except ValueError as e:
        raise SystemExit(f"error: --variants: {variant!r}: {e}") from None


def settings(variant: str, mode: str = "offline") -> dict:
    """The ``Tracker`` keyword arguments of a variant name (see the module docstring) in
    ``mode`` (the shape variants start from that mode's ``ShapeFitSettings.tracking``)."""
    tracking = pt.ShapeFitSettings.tracking("online" if mode == "online" else "offline")
    if variant == "default":
        return {}
    if variant.startswith("smoothleg"):  # smoothlegW[-free]: the leg terms in the smoother only
        motion = pt.SmoothSettings()
        residuals = _leg_terms(variant, "smoothleg", motion.residuals, ("", "free"))
        return {"motion": dataclasses.replace(motion, residuals=residuals)}
    if variant.startswith("legcross"):  # legcrossW[-free|-freeside]: the leg terms in the fits
        fit = pt.TrackerConfig().fit
        residuals = _leg_terms(variant, "legcross", fit.residuals, ("", "free", "freeside"))
        return {"config": pt.TrackerConfig(fit=dataclasses.replace(fit, residuals=residuals))}
    if variant == "inbatch":
        return {"config": pt.TrackerConfig(consensus_in_batch=True)}
    if variant == "far2d":  # before the numbered "far" variants
        return {"config": pt.TrackerConfig(far_side_2d=True)}
    if variant == "farbound":  # ungated in every mode (online the default gates it)
        return {"config": pt.TrackerConfig(far_side_bound=True, bound_trusted=False)}
    if variant == "nobound":  # online: the default before 2026-12-07
        return {"config": pt.TrackerConfig(far_side_bound=False)}
    if variant == "farboundT":  # the bound only behind a pose that passed the loss test
        return {"config": pt.TrackerConfig(far_side_bound=True, bound_trusted=True)}
    if variant.startswith("farboundT-axes") and variant[14:].isdigit():
        # farboundT-axesN: the trusted bound with the side view's restart from the facing
        config = pt.TrackerConfig(
            far_side_bound=True,
            bound_trusted=True,
            reinit_partial_frames=int(variant[14:]),
            reinit_partial_axes=True,
        )
        return {"config": config}
    if variant.startswith("farbound"):  # farboundS: the bound from a turn of sine S
        try:
            turn = float(variant[len("farbound") :])
            config = pt.TrackerConfig(far_side_bound=True, bound_trusted=False, bound_turn_sin=turn)
            return {"config": config}
        except ValueError as e:
            raise SystemExit(f"error: --variants: {variant!r}: {e}") from None
    if variant.startswith("axes") and variant[4:].isdigit():
        # axesN: reinit_partial_frames=N restarting from the last tracked pose's facing only
        config = pt.TrackerConfig(reinit_partial_frames=int(variant[4:]), reinit_partial_axes=True)
        return {"config": config}
    if variant.startswith("partial") or "-partial" in variant:
        # partialN: TrackerConfig(reinit_partial_frames=N); aloneM-partialN: with aloneM
        rest, _, frames = variant.rpartition("partial")
        try:
            out = {"config": pt.TrackerConfig(reinit_partial_frames=int(frames))}
        except ValueError as e:
            raise SystemExit(f"error: --variants: {variant!r}: {e}") from None
        return {**(settings(rest.removesuffix("-"), mode) if rest else {}), **out}
    if variant.startswith("spread") and variant[6:].isdigit():  # online refinements in parts
        return {"refine": dataclasses.replace(tracking, online_spread=int(variant[6:]))}
    if variant.startswith("alone"):  # aloneN: the mode's follower, alone_frames=N
        try:
            return {"follow": pt.FollowSettings.for_mode(mode, alone_frames=int(variant[5:]))}
        except ValueError as e:
            raise SystemExit(f"error: --variants: {variant!r}: {e}") from None
    for prefix, (kwarg, make, field, kind) in _NUMBERED.items():
        if variant.startswith(prefix):
            try:
                return {kwarg: make(**{field: kind(variant[len(prefix) :])})}
            except ValueError as e:
                raise SystemExit(f"error: --variants: {variant!r}: {e}") from None
    for prefix, (field, kind) in _ONLINE_SIDES.items():
        if variant.startswith(prefix):
            try:
                value = kind(variant[len(prefix) :])
                return {"sides": pt.SideSettings.for_mode("online", **{field: value})}
            except ValueError as e:
                raise SystemExit(f"error: --variants: {variant!r}: {e}") from None
    if variant == "grouparb":
        return {"sides": pt.SideSettings.for_mode(mode, arbitrate_groups=True)}
    if variant == "ogroups":
        return {"sides": pt.SideSettings.for_mode(mode, online_groups=True)}
    if variant == "checkfit":
        return {"config": pt.TrackerConfig(reinit_check_fit=True)}
    if variant.startswith("checkfit") and variant[8:].isdigit():
        frames = int(variant[8:])
        return {"config": pt.TrackerConfig(reinit_check_fit=True, reinit_check_frames=frames)}
    if variant.startswith("tracked") and variant[7:].isdigit():
        return {"config": pt.TrackerConfig(reinit_check_tracked=int(variant[7:]))}
    if variant.startswith("cdelta") and variant[6:].isdigit():
        return {"config": pt.TrackerConfig(reinit_check_delta=int(variant[6:]) / 1000)}
    if variant == "bothways":
        return {"motion": pt.SmoothSettings(both_ways=True)}
    if variant == "crossfade":
        return {"motion": pt.SmoothSettings(crossfade=True)}
    if variant == "bothways-crossfade":
        return {"motion": pt.SmoothSettings(both_ways=True, crossfade=True)}
    kind, _, values = variant.partition("prior")
    if kind in ("", "r") and "/" in values:
        sigma, _, change = values.partition("/")
        field = "radius_prior_sigma" if kind == "r" else "prior_sigma"
        try:
            return {"refine": dataclasses.replace(
                tracking, **{field: float(sigma)}, max_change=float(change)
            )}  # fmt: skip
        except ValueError as e:
            raise SystemExit(f"error: --variants: {variant!r}: {e}") from None
    if variant.startswith("girth"):
        try:
            return {"refine": dataclasses.replace(
                tracking, girth_prior_sigma=float(variant[5:])
            )}  # fmt: skip
        except ValueError as e:
            raise SystemExit(f"error: --variants: {variant!r}: {e}") from None
    if variant.startswith("twopass"):
        try:
            refine = dataclasses.replace(tracking, radius_prior_sigma=float(variant[7:]))
        except ValueError as e:
            raise SystemExit(f"error: --variants: {variant!r}: {e}") from None
        return {"refine": refine, _SECOND_PASS: True}
    frames, kind = variant.removeprefix("prepass"), variant[-1:]
    frames = frames[:-1] if kind in ("r", "g") else frames
    if variant.startswith("prepass") and frames.isdigit() and int(frames) >= 10:
        if mode != "offline":
            raise SystemExit(f"error: --variants: {variant!r}: the shape pre-pass is offline's")
        fields = _RADII if kind == "r" else tracking.fields
        refine = (  # "g": the mode's own refinement (offline: the girth prior)
            tracking if kind == "g"
            else dataclasses.replace(tracking, radius_prior_sigma=10.0, fields=fields)
        )  # fmt: skip
        # The tracker's own pre-pass (the same as two trackers by hand: tests/test_smooth.py).
        return {"refine": dataclasses.replace(refine, offline_first=int(frames))}
    if variant.startswith("gate"):  # prepass40g where the first 40 frames are poorly observed
        if mode != "offline":
            raise SystemExit(f"error: --variants: {variant!r}: the shape pre-pass is offline's")
        try:
            return {"refine": dataclasses.replace(
                tracking, offline_first=40, offline_first_below=float(variant[4:])
            )}  # fmt: skip
        except ValueError as e:
            raise SystemExit(f"error: --variants: {variant!r}: {e}") from None
    if variant == "lvm":
        return {"config": pt.TrackerConfig.recommended("lvm")}
    if variant.startswith("lvm-tracked") and variant[11:].isdigit():
        lvm = pt.TrackerConfig.recommended("lvm")
        return {"config": lvm.replace(reinit_check_tracked=int(variant[11:]))}
    if variant == "alllm-norefit":
        return {"config": pt.TrackerConfig(all_landmarks_hypothesis=True, consensus_refit=False)}
    if variant == "alllm":
        return {"config": pt.TrackerConfig(all_landmarks_hypothesis=True)}
    if variant == "norefit":
        return {"config": pt.TrackerConfig(consensus_refit=False)}
    if variant == "kept":
        return {"duplicates": None}
    if variant.startswith("settle") and variant[6:].isdigit():
        return {"duplicates": pt.DuplicateSettings(settle=int(variant[6:]))}
    if variant.startswith("turns"):  # turnsX: the mode's sides, frontal_turns=X
        try:
            return {"sides": pt.SideSettings.for_mode(mode, frontal_turns=float(variant[5:]))}
        except ValueError as e:
            raise SystemExit(f"error: --variants: {variant!r}: {e}") from None
    if variant.startswith("sides:"):
        names, with_limbs = variant[6:].removesuffix("/with-limbs"), variant.endswith("/with-limbs")
        groups = tuple(names.split("+"))
        try:
            return {"sides": pt.SideSettings(groups=groups, torso_with_limbs=with_limbs)}
        except ValueError as e:
            raise SystemExit(f"error: --variants: {variant!r}: {e}") from None
    raise SystemExit(
        f"error: --variants: {variant!r} is none of 'default', 'inbatch', 'norefit', 'alllm', "
        "'alllm-norefit', 'lvm', 'lvm-trackedN', 'oaccX', 'orobustX', 'owinN', 'anchorX', "
        "'amargX', 'oframesN', 'omodelX', "
        "'bothways', 'crossfade', 'bothways-crossfade', 'kept', 'settleN', 'bandM', 'confX', "
        "'agreeX', 'followX', 'aloneN', 'grouparb', 'ogroups', 'checkfit', "
        "'checkfitN', 'trackedN', 'cdeltaN', 'farboundS', 'farboundT', 'farboundT-axesN', "
        "'nobound', 'axesN', 'farX', "
        "'priorS/M', 'rpriorS/M', 'girthS', 'twopassS', "
        "'prepassN[r|g]' (N >= 10), 'gateX', 'turnsX', 'sides:G+G...'"
    )


#: The part radii among the body-shape fields (``prepassNr``).
_RADII = tuple(f for f in pt.ShapeFitSettings().fields if f.endswith("_radius"))
#: The ``settings`` key of the ``twopassS`` variants (not a ``Tracker`` keyword).
_SECOND_PASS = "second_pass"


def recorded(out: str, names: list[str]) -> set[tuple]:
    """``(group, seed, occ, tracker seed)`` of the records in the JSON-lines file ``out`` (none
    if it does not exist) that hold every variant of ``names``. A last line cut off mid-write
    (the process killed) is removed from the file, so appending goes on from a whole record; a
    bad line anywhere else is an error naming the file and line."""
    path = Path(out)
    if not path.is_file():
        return set()
    lines = path.read_text().splitlines(keepends=True)
    done = set()
    for i, line in enumerate(lines):
        try:
            rec = json.loads(line)
        except json.JSONDecodeError:
            if i == len(lines) - 1 and not line.endswith("\n"):
                tmp = path.with_name(path.name + ".tmp")
                tmp.write_text("".join(lines[:-1]))
                tmp.replace(path)
                print(f"{out}: removed a last line cut off mid-write", flush=True)
                break
            raise SystemExit(f"error: {out}, line {i + 1}: not a JSON record") from None
        if all(name in rec for name in names):
            done.add((rec["group"], rec["seed"], rec["occ"], rec["tseed"]))
    return done


def track(todo: list, variants: dict[str, dict], mode: str, out: str) -> None:
    """Track each ``((group, seed, motion, variety), occlusion, tracker seed)`` of ``todo``
    with every variant (name -> ``Tracker`` keywords) and append one JSON line per item to
    ``out`` (also printed): D, coverage, swapped-limb frames, acceleration error, detections
    dropped, seconds, the step's median ms a frame, the mean Delta of the tracked frames,
    online the motion model's median ms a frame, and for every variant after the first its
    D and swapped-limb frames and the first variant's over the frames both answered
    (``"shared"``, :func:`tune.shared_measures`; ``paired.py --shared`` reads them).

    Items already in ``out`` with every variant are skipped (:func:`recorded`): a screen cut
    short (a session's end, a killed process) resumes where it stopped."""
    done = recorded(out, list(variants))
    if done:
        print(f"{out}: {len(done)} runs already recorded with every variant, skipped", flush=True)
    with open(out, "a") as f:
        for (group, seed, motion, variety), occ, ts in todo:
            if (group, seed, occ, ts) in done:
                continue
            seq = generate_clip(seed, motion, variety, occ)
            rec = {"group": group, "seed": seed, "motion": motion, "occ": occ, "tseed": ts}
            first = None  # the first variant's keypoints: the others' "shared" baseline
            for name, kwargs in variants.items():
                t0 = time.perf_counter()
                kwargs = dict(kwargs)
                second = kwargs.pop(_SECOND_PASS, False)
                tr = pt.Tracker(seq.intrinsics, mode=mode, seed=ts, **kwargs)
                res = tr.run(seq.depth, seq.keypoints2d, seq.confidence)
                if second:  # again, from the first pass's refined shape
                    tr = pt.Tracker(seq.intrinsics, mode=mode, seed=ts, shape=res.shape, **kwargs)
                    res = tr.run(seq.depth, seq.keypoints2d, seq.confidence)
                rec[name] = {
                    **decision_measures(res.keypoints3d, seq.joints3d),
                    "dropped": tr.duplicates_dropped, "s": time.perf_counter() - t0,
                    "step_ms": res.ms_per_frame,
                    # Mean Delta of the per-frame poses (offline: the forward pass's) over the
                    # tracked frames: what the tracker itself can see of a track's quality.
                    "delta": float(np.nanmean(np.where(res.status == 0, res.delta, np.nan))),
                }  # fmt: skip
                if mode == "online":  # the online motion model's median time per frame
                    rec[name]["motion_ms"] = float(np.median(tr.motion_times) * 1000)
                if first is None:
                    first = (name, res.keypoints3d)
                else:  # D and swaps over the frames both this and the first variant answered
                    shared = shared_measures(res.keypoints3d, first[1], seq.joints3d)
                    rec[name]["shared"] = {"vs": first[0], **shared}
            f.write(json.dumps(rec) + "\n")
            f.flush()
            print(json.dumps(rec), flush=True)


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument(
        "out", help="JSON lines, appended to; runs already there with every variant are skipped"
    )
    ap.add_argument("--variants", default="kept,settle1")
    ap.add_argument("--mode", choices=("offline", "online", "per-frame"), default="offline")
    ap.add_argument("--tracker-seeds", default="0,1")
    add_part_arguments(ap)
    ap.add_argument(
        "--real-seeds", help="instead of the 40 clips: wide real motion clips, e.g. 100-123"
    )
    ap.add_argument(
        "--procedural-seeds", help="instead of the 40 clips: wide procedural clips, e.g. 171-173"
    )
    ap.add_argument("--standard-seeds", help="instead of the 40 clips: standard procedural clips")
    ap.add_argument(
        "--side-seeds", help="add wide walk_across clips (a side view) of these tuning seeds"
    )
    ap.add_argument(
        "--cmu-late-seeds",
        help="add CMU subject 131 clips from 4.2 s on (after the report clips' stretch)",
    )
    ap.add_argument("--no-base", action="store_true", help="only the added clips, not the 40")
    a = ap.parse_args()
    check_part(ap, a)
    if a.no_base and a.side_seeds is None and a.cmu_late_seeds is None:
        ap.error("--no-base leaves only the added clips: give --side-seeds or --cmu-late-seeds")
    side, real, procedural, standard, cmu = (
        None if text is None else parse_seeds(text)
        for text in (
            a.side_seeds,
            a.real_seeds,
            a.procedural_seeds,
            a.standard_seeds,
            a.cmu_late_seeds,
        )
    )
    chosen = clips(real, side, not a.no_base, procedural, standard, cmu)
    variants = {v: settings(v, a.mode) for v in a.variants.split(",")}
    seeds = [int(s) for s in a.tracker_seeds.split(",")]
    todo = share([(c, occ, ts) for c in chosen for occ in (0, 2) for ts in seeds], a)
    track(todo, variants, a.mode, a.out)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
