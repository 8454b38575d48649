"""The ``posetrack`` command line: ``demo``, ``generate``, ``track``, ``warmup``."""

from __future__ import annotations

import argparse
import os
import sys
import time

_DETECT_INSTALL = 'pip install ".[detect]" (from a posetrack checkout)'


def _demo(args) -> int:
    from ._demo import run_demo

    run_demo(
        args.out,
        frames=args.frames,
        methods=tuple(args.methods.split(",")),
        occlusion_levels=tuple(int(x) for x in args.occlusion.split(",")),
        motion=args.motion,
        seed=args.seed,
        progress=not args.quiet,
    )
    return 0


def _generate(args) -> int:
    from .. import synth
    from ._progress import ProgressBar

    if os.path.exists(args.out) and not args.overwrite:
        raise FileExistsError(
            f"generate: {args.out} already exists; choose another folder or pass --overwrite"
        )
    seq = synth.generate(
        args.seed, motion=args.motion, n_frames=args.frames, occlusion_level=args.occlusion,
        width=args.width, height=args.height,
        progress=None if args.quiet else ProgressBar("generating"),
        bystander=args.second_person, variety=args.variety,
    )  # fmt: skip
    synth.save(seq, args.out, overwrite=args.overwrite)
    print(f"wrote {len(seq.depth)} frames to {args.out}")
    return 0


def _load_detector():
    """``posetrack.detect.detect_keypoints``, or a clear error if the extra is missing.

    Checked before the recording is loaded, so a missing extra fails in a second, not after
    loading: ``posetrack.detect`` imports without MediaPipe, and ``available()`` tries it.
    """
    missing = (
        "--detect needs the optional 2D keypoint detector (MediaPipe BlazePose with its "
        f"bundled models), which cannot be loaded here{{}}; install it with: {_DETECT_INSTALL}"
    )
    try:
        from .. import detect
    except ImportError as e:
        raise ValueError(missing.format(f" ({e})")) from None
    available = getattr(detect, "available", None)
    if available is not None and not available():
        raise ValueError(missing.format(""))
    return detect.detect_keypoints


def _detected(detect_keypoints, rgb, n: int, *, progress: bool):
    """Run the built-in detector on the colour frames; checks what it returns."""
    import numpy as np

    try:
        kp2d, conf = detect_keypoints(rgb, progress=progress)
    except ImportError as e:  # the extra broke between the check and the call
        raise ValueError(f"--detect: {e}") from None
    kp2d, conf = np.asarray(kp2d, np.float32), np.asarray(conf, np.float32)
    if kp2d.shape != (n, 18, 2) or conf.shape != (n, 18):
        raise ValueError(
            f"--detect: the detector returned keypoints {kp2d.shape} and confidence "
            f"{conf.shape}; expected ({n}, 18, 2) and ({n}, 18)"
        )
    return kp2d, conf


def _tracker_config(args):
    """``TrackerConfig.recommended`` for ``--method`` / ``--hypotheses`` (``track``, ``warmup``)."""
    from .._config import TrackerConfig

    if args.hypotheses is not None and args.hypotheses < 1:
        raise ValueError(f"--hypotheses must be at least 1, got {args.hypotheses}")
    overrides = {}
    if args.hypotheses is not None:
        if args.method == "lvm":
            print("note: --hypotheses ignored: lvm uses one hypothesis", file=sys.stderr)
        else:
            overrides["num_hypotheses"] = args.hypotheses
    return TrackerConfig.recommended(args.method, **overrides)


def _mode(args) -> str:
    """The motion-model mode of ``--online`` / ``--per-frame`` (``track``, ``warmup``)."""
    return "online" if args.online is not None else ("per-frame" if args.per_frame else "offline")


def _lag(args) -> int:
    """The online lag of ``--online [LAG]`` (``ONLINE_LAG`` without a value; 0 offline)."""
    return 0 if args.online is None else args.online


def _motion(args):
    """The tracker's ``motion`` for ``--both-ways`` / ``--one-way`` (``track``,
    ``track-many``); offline only."""
    from .._smooth import SmoothSettings

    if args.both_ways is None:
        return SmoothSettings()
    if _mode(args) != "offline":
        flag = "--both-ways" if args.both_ways else "--one-way"
        raise ValueError(f"{flag} applies offline only (not with --online or --per-frame)")
    return SmoothSettings(both_ways=args.both_ways)


def _refine(args):
    """The tracker's ``refine`` for ``--no-refine-shape``, ``--shape-prepass N`` and
    ``--shape-prepass-below X`` (``track``, ``track-many``, ``warmup``): None, ``"auto"`` or
    the offline ``ShapeFitSettings`` with ``offline_first=N`` (``offline_first_below=X``)."""
    import dataclasses

    from .._shapefit import ShapeFitSettings

    n, below = args.shape_prepass, args.shape_prepass_below
    if below is not None and not n:
        raise ValueError(
            f"--shape-prepass-below {below} gates the shape pre-pass: it needs --shape-prepass N"
        )
    if not n:
        return None if args.no_refine_shape else "auto"
    if args.no_refine_shape:
        raise ValueError(
            f"--shape-prepass {n} refines the body shape: it does not go with --no-refine-shape"
        )
    if _mode(args) != "offline":
        raise ValueError(
            f"--shape-prepass {n} is the offline mode's: it does not go with --online or "
            "--per-frame"
        )
    flags = f"--shape-prepass {n}" + ("" if below is None else f" --shape-prepass-below {below}")
    try:
        return dataclasses.replace(
            ShapeFitSettings.tracking("offline"), offline_first=n, offline_first_below=below
        )  # fmt: skip
    except ValueError as e:
        raise ValueError(f"{flags}: {e}") from None


def _track(args) -> int:
    import numpy as np

    from .. import io
    from .._limbs import LIMB_NAMES
    from .._sides import SideSettings
    from .._tracker import Tracker
    from ._export import check_output_dir, save_results, status_counts
    from ._progress import ProgressBar, note_when_done

    t_start = time.perf_counter()
    progress = not args.quiet
    refine = _refine(args)  # flags that do not go together: before any file is read
    detect_keypoints = None
    if args.tum is not None:
        if args.rgb is not None:
            raise ValueError("--rgb is not used with --tum: the sequence's rgb/ is the colour")
    elif args.intrinsics is None:
        raise ValueError("--intrinsics FILE is required with --depth (the depth camera's)")
    if args.detect:
        if args.rgb is None and args.tum is None:
            raise ValueError(
                "--detect needs --rgb DIR|VIDEO (the colour frames to detect in) or --tum"
            )
        if args.keypoints is not None:
            raise ValueError("give either --keypoints DIR or --detect, not both")
        if args.person_id is not None:
            raise ValueError("--person-id selects a person in OpenPose files; not with --detect")
        detect_keypoints = _load_detector()
    elif args.keypoints is None:
        raise ValueError(
            "--keypoints DIR is required (OpenPose JSON), or --detect with --rgb to detect "
            f"keypoints with the built-in detector ({_DETECT_INSTALL})"
        )
    config = _tracker_config(args)  # bad --hypotheses fails before loading
    if args.fps is not None and not (np.isfinite(args.fps) and args.fps > 0):
        raise ValueError(f"--fps must be positive, got {args.fps}")
    out = check_output_dir(args.out)  # before the long part: a bad --out fails now

    options = dict(
        keypoints_dir=args.keypoints, intrinsics_path=args.intrinsics, person_id=args.person_id,
        allow_missing=args.allow_missing, out_of_image="drop" if args.drop_outside else "error",
        keypoints_scale=args.keypoints_scale,
    )  # fmt: skip
    if args.tum is not None:
        depth_scale = io.TUM_DEPTH_SCALE if args.depth_scale is None else args.depth_scale
        max_difference = args.tum_max_difference
        rec = io.load_tum(
            args.tum, depth_scale=depth_scale, **options,
            max_difference=io.TUM_MAX_DIFFERENCE if max_difference is None else max_difference,
        )  # fmt: skip
    else:
        if args.tum_max_difference is not None:
            raise ValueError("--tum-max-difference applies to --tum only")
        depth_scale = 1000.0 if args.depth_scale is None else args.depth_scale
        rec = io.load_recording(
            depth_dir=args.depth, rgb=args.rgb, depth_scale=depth_scale, **options
        )
    notes = list(rec.notes)
    for note in notes:
        print(f"note: {note}", file=sys.stderr)
    n = len(rec)
    t_loaded = time.perf_counter()
    if detect_keypoints is not None:
        kp2d, conf = _detected(detect_keypoints, rec.rgb, n, progress=progress)
        nobody = rec.frame_ids[~(conf > 0).any(axis=1)]
        if nobody.size:
            notes.append(
                f"detector: nobody found in {nobody.size} frame(s) "
                f"({io.format_ranges(nobody.tolist())}): frames without observation"
            )
            print(f"note: {notes[-1]}", file=sys.stderr)
    else:
        # Every detected person: the tracker chooses one and follows it.
        kp2d, conf = rec.people2d, rec.people_confidence
    # Frames without observation (no depth file, nobody detected) carry no keypoints at all.
    conf = np.where(rec.observed.reshape((-1,) + (1,) * (conf.ndim - 1)), conf, np.float32(0))
    t_detected = time.perf_counter()
    detected = None  # the detector's keypoints, saved so a run can be repeated without it
    if detect_keypoints is not None:
        if args.tum is not None:  # OpenPose names files after the image: --tum pairs by them
            stems = [os.path.splitext(os.path.basename(p))[0] for p in rec.rgb.paths]
        else:  # by frame number, as the depth folder pairs
            stems = [f"{int(i):06d}" for i in rec.frame_ids]
        detected = (kp2d, conf, stems)

    w, h = rec.intrinsics.width, rec.intrinsics.height
    print(
        f"tracking {n} frames ({w}x{h}) with {config.method}, {config.n} hypothes"
        f"{'is' if config.n == 1 else 'es'} (the first frames include JAX compilation)",
        file=sys.stderr,
    )
    fps = args.fps if args.fps is not None else rec.fps  # None: unknown (not written)
    mode = _mode(args)
    tracker = Tracker(
        rec.intrinsics, config, seed=args.seed, person=args.person, mode=mode,
        lag=_lag(args), fps=30.0 if fps is None else fps,
        sides={None: "auto", True: SideSettings.for_mode(mode), False: None}[args.fix_sides],
        refine=refine, duplicates=None if args.keep_duplicates else "auto",
        motion=_motion(args),
    )  # fmt: skip
    bar = ProgressBar("tracking") if progress else None
    if bar is not None and mode == "offline":  # seconds after the bar fills: say what runs
        shape = "refining the body shape against the depth, then " if tracker.refine else ""
        bar = note_when_done(bar, f"offline: {shape}smoothing the motion over all {n} frames")
    result = tracker.run(rec.depth, kp2d, conf, progress=bar)
    undone = (  # frames with each left/right group read exchanged (--fix-sides)
        None
        if result.exchanged is None
        else {g: int(n) for g, n in zip(tracker.sides.groups, result.exchanged.sum(axis=0))}
    )
    interpolated = (  # frames where the motion model started each limb from its neighbours
        None
        if result.interpolated is None
        else {n: int(k) for n, k in zip(LIMB_NAMES, result.interpolated.sum(axis=0))}
    )
    t_tracked = time.perf_counter()
    person = _person_summary(result, rec.frame_ids, args.person)
    if kp2d.ndim == 4:  # the followed person's detections, for the overlay and the files
        kp2d, conf = _followed_detections(result, kp2d, conf)

    info = {
        "inputs": {
            "depth": None if args.depth is None else os.path.abspath(args.depth),
            "tum": None if args.tum is None else os.path.abspath(args.tum),
            "keypoints": None if args.keypoints is None else os.path.abspath(args.keypoints),
            "keypoints_source": "posetrack.detect" if args.detect else rec.keypoint_layout,
            "rgb": None if args.rgb is None else os.path.abspath(args.rgb),
            "intrinsics": None if args.intrinsics is None else os.path.abspath(args.intrinsics),
            "depth_scale": depth_scale,
            "person_id": args.person_id,
            "person": args.person,
            "allow_missing": args.allow_missing,
            "drop_outside": args.drop_outside,
            "keypoints_scale": args.keypoints_scale,
            "seed": args.seed,
            "mode": mode,
            "lag": _lag(args),
            "fix_sides": tracker.sides is not None,
            "drop_duplicates": tracker.duplicates is not None,
            "refine_shape": not args.no_refine_shape,
            "shape_prepass": tracker.prepass_frames(len(rec.depth)),
            "shape_prepass_below": args.shape_prepass_below,
        },
        "notes": notes,
        # Seconds of each frame (TUM: the colour image's time stamp); null without them.
        "frame_timestamps": None if rec.timestamps is None else rec.timestamps.tolist(),
        "person": person,
        "sides_exchanged": undone,
        # Frames (0-based indices) whose re-initialisation read every left/right pair
        # exchanged to keep the lost track's facing (TrackerConfig.reinit_keep_facing).
        "facing_kept_at_reinit": list(tracker.reinit_flip_frames),
        # Offline: frames where a limb's per-frame pose followed a doubtful keypoint jump and
        # the motion model started it from its neighbours' pose (null: no offline smoothing).
        "limbs_interpolated": interpolated,
        # Each stretch tracked both ways (offline: read exchanged from both directions;
        # online: the first frames of each exchange read forwards).
        "sides_arbitrated": [
            {"start": a, "stop": b, "delta_detected": da, "delta_exchanged": dx, "kept": k}
            for a, b, da, dx, k in tracker.side_spans
        ],
        # Keypoint detections dropped because they jumped onto another keypoint (offline and
        # online; --keep-duplicates: 0).
        "detections_dropped": tracker.duplicates_dropped,
        "shape_refinement": _shape_summary(tracker),
        "timing": {
            "load_s": t_loaded - t_start,
            "detect_s": t_detected - t_loaded if args.detect else None,
            "track_s": t_tracked - t_detected,
        },
    }
    saved = save_results(
        out, result, intrinsics=rec.intrinsics, frame_ids=rec.frame_ids, fps=fps,
        rgb=rec.rgb, depth=rec.depth, video=not args.no_video, video_panel=_video_panel(args),
        detections=(kp2d, conf), keypoints2d=detected, info=info, progress=progress,
        frame=args.frame,
    )  # fmt: skip

    counts = status_counts(result.status)
    tracked = result.status == 0
    mean_delta = f"{np.mean(result.delta[tracked]):.3f}" if tracked.any() else "n/a"
    total = time.perf_counter() - t_start
    print(
        f"{n} frames: {counts['tracked']} tracked, {counts['lost']} lost, "
        f"{counts['no_observation']} without observation; mean Delta {mean_delta} "
        f"(tracked frames)"
    )
    rep = tracker.refine_report
    if rep is not None:
        scaled = {k: v for k, v in rep["factors"].items() if k != "shoulder_drop"}
        top = sorted(scaled, key=lambda k: -abs(np.log(scaled[k])))[:3]
        first = rep.get("offline_first")
        print(
            f"body shape refined against the depth of {len(rep['frames_used'])} frames "
            f"({tracker.refine_s:.1f} s): " + ", ".join(f"{k} x{scaled[k]:.2f}" for k in top)
            + ("" if first is None else f" (after the shape pre-pass's refinement on "
               f"{len(first['frames_used'])} of the first {tracker.prepass_frames(n)} frames, "
               f"{tracker.prepass_s:.1f} s with its tracking)")
        )  # fmt: skip
    if tracker.prepass_share is not None and not tracker.prepass_s:  # the gate kept it off
        print(
            f"no shape pre-pass: {tracker.prepass_share:.2f} of the first "
            f"{tracker.prepass_frames(n)} frames' keypoints observed on depth (the gate, "
            f"--shape-prepass-below, is {args.shape_prepass_below})"
        )
    if undone and any(undone.values()):
        listed = ", ".join(f"{g} {n}" for g, n in undone.items() if n)
        print(f"left/right swaps of the detector undone (frames): {listed}")
    if tracker.reinit_flip_frames:
        print(
            "re-initialised with every left/right pair exchanged, keeping the lost track's "
            f"facing (frames): {', '.join(map(str, tracker.reinit_flip_frames))}"
        )
    if tracker.duplicates_dropped:
        print(
            f"keypoint detections dropped (jumped onto another keypoint): "
            f"{tracker.duplicates_dropped}"
        )
    if interpolated and any(interpolated.values()):
        listed = ", ".join(f"{n} {k}" for n, k in interpolated.items() if k)
        print(f"limbs started from their neighbours' pose by the motion model (frames): {listed}")
    if person["max_people"] > 1:
        print(
            f"person: followed people[{person['first_index']}] of frame "
            f"{person['first_frame']} (--person {args.person}); other people ignored in "
            f"{person['frames_others_ignored']} frame(s); the followed person not found among "
            f"others in {person['frames_lost_among_others']} frame(s) (lost)"
        )
    steady = (
        f", {result.ms_per_frame:.0f} ms/frame after that"
        if np.isfinite(result.ms_per_frame)
        else ""
    )
    print(f"time: {total:.1f} s (compile {result.compile_s:.1f} s{steady})")
    files = ["poses.npz", "keypoints3d/", "motion.bvh", "markers.trc"]
    if saved.overlay is not None:
        files.append(saved.overlay.name)
    files.append("summary.json")
    print(f"wrote {out}/ ({args.frame} frame): {', '.join(files)}")
    if not tracked.any():
        print(
            "warning: no frame was tracked; check that the keypoints belong to the depth "
            "images (same camera, registered) and that the person is in range",
            file=sys.stderr,
        )
    return 0


def _track_many(args) -> int:
    from ._many import track_many_command

    return track_many_command(args)


def _followed_detections(result, people2d, people_conf):
    """Each frame's detection of the followed person, from every person's ``(T, P, 18, 2)``
    keypoints and ``(T, P, 18)`` confidences (confidence 0 where nobody was followed)."""
    import numpy as np

    t = np.arange(len(result.person_index))
    pick = np.maximum(result.person_index, 0)
    followed = result.person_index >= 0
    conf = np.where(followed[:, None], people_conf[t, pick], np.float32(0))
    return people2d[t, pick], conf


def _person_summary(result, frame_ids, rule) -> dict:
    """Who was followed, for the summary line and summary.json."""
    import numpy as np

    followed = np.flatnonzero(result.person_index >= 0)
    first = int(followed[0]) if followed.size else None
    lost_among = (result.person_index < 0) & (result.num_people > 0) & (result.status == 1)
    return {
        "rule": rule,
        "first_frame": None if first is None else int(frame_ids[first]),
        "first_index": None if first is None else int(result.person_index[first]),
        "max_people": int(result.num_people.max(initial=0)),
        "frames_followed": int(followed.size),
        "frames_others_ignored": result.others_ignored,
        "frames_lost_among_others": int(lost_among.sum()),
        "person_index": [int(i) for i in result.person_index],
    }


def _person_arg(value: str):
    from .._associate import PERSON_RULES

    if value in PERSON_RULES:
        return value
    try:
        index = int(value)
    except ValueError:
        index = -1
    if index < 0:
        raise argparse.ArgumentTypeError(
            f"expected auto, largest, closest or a person index >= 0, got {value!r}"
        )
    return index


def _size_arg(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected WIDTHxHEIGHT, e.g. 640x480, got {text!r}")
    if w < 8 or h < 8:
        raise argparse.ArgumentTypeError(f"image size must be at least 8x8, got {text!r}")
    return w, h


def _warmup(args) -> int:
    from .. import io
    from .._camera import Intrinsics
    from .._programs import cache_dir
    from .._tracker import Tracker

    folder = cache_dir()
    if folder is None:
        raise ValueError(
            "warmup: the cache is off (POSETRACK_CACHE_DIR=off, or its folder is not "
            "writable); there is nothing to fill"
        )
    if (args.intrinsics is None) == (args.size is None):
        raise ValueError("warmup: give the depth camera as --intrinsics FILE or --size WxH")
    if args.intrinsics is not None:
        intrinsics = io.read_intrinsics(args.intrinsics)
    else:
        w, h = args.size
        intrinsics = Intrinsics(fx=0.9 * w, fy=0.9 * w, cx=w / 2, cy=h / 2, width=w, height=h)
    config, mode = _tracker_config(args), _mode(args)
    t0 = time.perf_counter()
    Tracker(intrinsics, config, mode=mode, lag=_lag(args), refine=_refine(args)).prepare()
    print(
        f"warmup: {config.method}, {config.n} hypothes{'is' if config.n == 1 else 'es'}, "
        f"{intrinsics.width}x{intrinsics.height}, {mode}: ready in {folder.parent} "
        f"({time.perf_counter() - t0:.1f} s)"
    )
    return 0


def _shape_summary(tracker) -> dict:
    """``summary.json``'s ``shape_refinement``: whether the body dimensions (``shape``) were
    refined against the depth, by what factor (``shoulder_drop``: metres added) and on which
    frames (indices into the recording)."""
    rep = tracker.refine_report
    out = {
        "refined": rep is not None,
        "factors": None if rep is None else {k: round(v, 4) for k, v in rep["factors"].items()},
        "refined_on_frames": None if rep is None else [int(t) for t in rep["frames_used"]],
        "refine_s": None if rep is None else round(tracker.refine_s, 2),
    }
    # --shape-prepass-below: the share of the pre-pass's frames' keypoints observed on depth
    # (the pre-pass ran where it was below the gate); null without the gate.
    share = tracker.prepass_share
    out["prepass_observed_share"] = None if share is None else round(share, 4)
    first = None if rep is None else rep.get("offline_first")
    if first is not None:  # --shape-prepass: its refinement, the start of the one above
        out["prepass"] = {
            "factors": {k: round(v, 4) for k, v in first["factors"].items()},
            "refined_on_frames": [int(t) for t in first["frames_used"]],
            "prepass_s": round(tracker.prepass_s, 2),
        }
    return out


def _add_method_options(p: argparse.ArgumentParser) -> None:
    """``--method`` and ``--hypotheses`` (``track`` and ``warmup``)."""
    p.add_argument(
        "--method", choices=("lvm", "mht_r", "mht_g", "mht_h"), default="mht_h",
        help="tracker variant (default: %(default)s, the recommended MHT_h; the others use "
        "the paper's best settings)",
    )  # fmt: skip
    p.add_argument(
        "--hypotheses", type=int, metavar="N",
        help="number of hypotheses (default: 10 for mht_h; the paper's 5 for mht_g, 20 for mht_r)",
    )  # fmt: skip


def _add_mode_options(p: argparse.ArgumentParser) -> None:
    """``--online [LAG]`` / ``--per-frame``, ``--no-refine-shape`` and ``--shape-prepass N``
    (``track``, ``track-many`` and ``warmup``)."""
    from .._tracker import ONLINE_LAG

    motion = p.add_mutually_exclusive_group()
    motion.add_argument(
        "--online", type=int, nargs="?", const=ONLINE_LAG, default=None, metavar="LAG",
        help="causal motion model, as for a live camera: each pose uses only the frames up to "
        f"LAG frames after it (default LAG {ONLINE_LAG}, {ONLINE_LAG / 30 * 1000:.0f} ms at "
        "30 fps; 0: no delay, shakier; see the README). Without this flag the motion model "
        "smooths over the whole recording (offline)",
    )  # fmt: skip
    motion.add_argument(
        "--per-frame", action="store_true",
        help="no motion model: every frame on its own (the paper's tracker)",
    )  # fmt: skip
    p.add_argument(
        "--no-refine-shape", action="store_true",
        help="keep the body dimensions measured between lifted keypoints instead of "
        "refining them against the depth of 8 frames (offline: after tracking; online: "
        "after 20 and after 60 tracked frames; saves about 3-8 s, costs accuracy; see the "
        "README)",
    )  # fmt: skip
    p.add_argument(
        "--shape-prepass", type=int, default=0, metavar="N",
        help="offline: track the first N frames alone first, refine the body shape on them "
        "and track the whole recording from that shape (N >= 8; off by default; 40 helped "
        "occluded recordings by 1-6 mm and cost clean ones up to 3.5: see the README)",
    )  # fmt: skip
    p.add_argument(
        "--shape-prepass-below", type=float, default=None, metavar="X",
        help="with --shape-prepass N: make the pre-pass only where the share of the first N "
        "frames' keypoints observed on depth is below X (0.6 separated clean starts from "
        "occluded ones; it kept the clean recordings' losses away, not the pre-pass's own: "
        "see the README)",
    )  # fmt: skip


def _add_passes_options(p: argparse.ArgumentParser) -> None:
    """``--both-ways`` / ``--one-way`` (``track`` and ``track-many``; offline)."""
    from .._smooth import SmoothSettings

    default = "both ways" if SmoothSettings().both_ways else "one way"
    passes = p.add_mutually_exclusive_group()
    passes.add_argument(
        "--both-ways", dest="both_ways", action="store_const", const=True, default=None,
        help="offline: track the recording a second time, from the last frame back to the "
        "first, smooth each pass and fuse the two (lower error where one pass goes wrong, "
        f"mostly under occlusion; twice the tracking steps). Default: {default}",
    )  # fmt: skip
    passes.add_argument(
        "--one-way", dest="both_ways", action="store_const", const=False,
        help="offline: one forward pass only (half the tracking steps of --both-ways)",
    )  # fmt: skip


def _add_video_options(p: argparse.ArgumentParser) -> None:
    """``--no-video`` and ``--video-panel`` (``track`` and ``track-many``)."""
    p.add_argument("--no-video", action="store_true", help="do not write the overlay video")
    p.add_argument(
        "--video-panel", choices=("side", "top", "none"), default="side",
        help="3D view beside the image in the overlay video: the skeleton from the side "
        "(depth across, height up) or from above, at one metric scale for the clip, with "
        "1.5 s trails and the floor; none: the image alone (default: %(default)s)",
    )  # fmt: skip


def _video_panel(args) -> str | None:
    """``--video-panel`` as ``save_results`` takes it."""
    return None if args.video_panel == "none" else args.video_panel


def _version() -> str:
    """The installed package's version (the source tree's when not installed)."""
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version("posetrack")
    except PackageNotFoundError:
        from .. import __version__

        return __version__


def build_parser() -> argparse.ArgumentParser:
    from ..synth import MOTIONS  # NumPy only: the help lists what generate accepts

    p = argparse.ArgumentParser(
        prog="posetrack",
        description="3D human pose tracking from RGB-D video and 2D keypoints (Makris & Argyros).",
    )
    p.add_argument("--version", action="version", version=f"posetrack {_version()}")
    sub = p.add_subparsers(dest="command", required=True)

    d = sub.add_parser(
        "demo", help="generate a synthetic RGB-D sequence, track it, print a table, write pictures"
    )
    d.add_argument(
        "--out",
        default="posetrack-demo",
        help="folder for pictures and numbers (default: %(default)s)",
    )
    d.add_argument(
        "--frames", type=int, default=60, help="frames per sequence (default: %(default)s)"
    )
    d.add_argument(
        "--methods", default="lvm,mht_h", help="comma-separated methods (default: %(default)s)"
    )
    d.add_argument(
        "--occlusion",
        default="0,2",
        help="comma-separated occlusion levels 0-4 (default: %(default)s)",
    )
    d.add_argument("--motion", default="walk", help="built-in motion (default: %(default)s)")
    d.add_argument("--seed", type=int, default=0)
    d.add_argument("--quiet", action="store_true", help="no progress bars")
    d.set_defaults(func=_demo)

    g = sub.add_parser(
        "generate",
        help="write a synthetic recording folder (depth PNGs, OpenPose JSON, intrinsics)",
    )
    g.add_argument(
        "out", help="output folder: depth/, rgb/, keypoints/, intrinsics.json, ground_truth.npz"
    )
    g.add_argument("--frames", type=int, default=60, help="frames (default: %(default)s)")
    g.add_argument(
        "--motion", default="walk",
        help=f"built-in motion ({', '.join(MOTIONS)}) or a motion-capture clip such as "
        "cmu:131_01 (posetrack.synth.list_real_motions(); needs the shared data folder) "
        "(default: %(default)s)",
    )  # fmt: skip
    g.add_argument(
        "--occlusion", type=int, default=0, choices=range(5), metavar="0-4",
        help="occluder level as in the paper's Fig. 4 (default: %(default)s)",
    )  # fmt: skip
    g.add_argument("--width", type=int, default=640, help="image width (default: %(default)s)")
    g.add_argument("--height", type=int, default=480, help="image height (default: %(default)s)")
    g.add_argument("--seed", type=int, default=0, help="random seed (default: %(default)s)")
    g.add_argument(
        "--second-person", action="store_true",
        help="a second person walks across the view, leaves and comes back (the keypoint "
        "files list both, in random order)",
    )  # fmt: skip
    g.add_argument(
        "--variety", choices=("standard", "wide"), default="standard",
        help="wide: a per-seed wider draw of body, camera, depth noise and detector errors "
        "(see posetrack.synth.generate) (default: %(default)s)",
    )  # fmt: skip
    g.add_argument("--overwrite", action="store_true", help="replace an existing output folder")
    g.add_argument("--quiet", action="store_true", help="no progress bar")
    g.set_defaults(func=_generate)

    t = sub.add_parser(
        "track",
        help="track a person in a recording (depth PNGs + OpenPose JSON) and write poses, "
        "BVH and an overlay video",
        description="Track one person through an RGB-D recording. Inputs: a folder of 16-bit "
        "depth PNGs (or a TUM RGB-D sequence folder, --tum), a folder of OpenPose JSON "
        "(COCO-18 or BODY_25) and the depth camera's intrinsics (JSON or OpenCV YAML/XML). "
        "Writes poses.npz, keypoints3d/*.json (EasyMocap), motion.bvh, overlay.mp4 (or .gif) "
        "and summary.json into --out, atomically.",
        epilog="Exit codes: 0 done, 2 bad input or arguments (one 'error:' line, nothing "
        "written), 1 system error (disk full, permissions; nothing written), 130 interrupted "
        "(nothing written). Set POSETRACK_TRACEBACK=1 to see tracebacks instead of 'error:' "
        "lines.",
    )
    source = t.add_mutually_exclusive_group(required=True)
    source.add_argument("--depth", metavar="DIR", help="folder of 16-bit depth PNGs")
    source.add_argument(
        "--tum", metavar="FOLDER",
        help="a TUM RGB-D sequence (rgb.txt, depth.txt, rgb/, depth/) instead of --depth: one "
        "frame per colour image (its rgb/ is the colour, as --rgb), depth paired by time "
        "stamp, depth scale 5000, intrinsics from the folder name (freiburg1/2/3) unless "
        "--intrinsics is given",
    )  # fmt: skip
    t.add_argument(
        "--keypoints", metavar="DIR",
        help="folder of OpenPose <stem>_keypoints.json files (not needed with --detect)",
    )  # fmt: skip
    t.add_argument(
        "--intrinsics", metavar="FILE",
        help="depth-camera intrinsics (required with --depth): JSON (Open3D, {fx, fy, cx, cy, "
        "width, height} or ROS CameraInfo) or OpenCV YAML/XML (camera_matrix, image_width, "
        "image_height; EasyMocap intri.yml: FILE#NAME chooses camera NAME). Without a size in "
        "the file, the depth images give it",
    )  # fmt: skip
    t.add_argument(
        "--rgb", metavar="DIR|VIDEO",
        help="colour frames registered to depth (folder or video): overlay background, "
        "and the input of --detect",
    )  # fmt: skip
    t.add_argument(
        "--detect", action="store_true",
        help=f"detect 2D keypoints in --rgb with the built-in detector ({_DETECT_INSTALL})",
    )  # fmt: skip
    _add_method_options(t)
    t.add_argument(
        "--depth-scale", type=float, metavar="S",
        help="depth units per metre (default: 1000 = millimetres; with --tum 5000)",
    )  # fmt: skip
    t.add_argument(
        "--tum-max-difference", type=float, metavar="SECONDS",
        help="with --tum: a colour image and its depth image are less than this apart "
        "(default: 0.02, as the benchmark's associate.py)",
    )  # fmt: skip
    t.add_argument(
        "--person-id", type=int, metavar="ID",
        help="OpenPose person_id to follow, when OpenPose's own tracking wrote ids (default: "
        "the tracker chooses, see --person)",
    )  # fmt: skip
    t.add_argument(
        "--person", type=_person_arg, default="auto", metavar="RULE",
        help="with several people in view, whom to follow: auto (the most complete detection, "
        "the closest of those), largest, closest, or an index into the first frame's list of "
        "people; chosen once, then followed (others are ignored) (default: %(default)s)",
    )  # fmt: skip
    t.add_argument(
        "--allow-missing", action="store_true",
        help="frames missing from one folder become frames without observation (default: error)",
    )  # fmt: skip
    t.add_argument(
        "--drop-outside", action="store_true",
        help="keypoints more than 16 px outside the image are marked missing (default: error)",
    )  # fmt: skip
    t.add_argument(
        "--keypoints-scale", type=float, metavar="S",
        help="scale keypoint pixels by S, pixel centre to pixel centre (keypoints detected on "
        "an image of another size than depth: 2 for half-size colour). Default: 1, but "
        "keypoints that all lie in the depth image's top-left quadrant are refused as "
        "half-size",
    )  # fmt: skip
    t.add_argument(
        "--fps", type=float,
        help="frame rate for the motion model, the BVH and the video (default: the video's, "
        "else 30)",
    )  # fmt: skip
    _add_mode_options(t)
    _add_passes_options(t)
    sides = t.add_mutually_exclusive_group()
    sides.add_argument(
        "--fix-sides", dest="fix_sides", action="store_const", const=True, default=None,
        help="undo the detector's left/right swaps of the arms, legs and torso before "
        "fitting. "
        "Default: on offline (read from both directions, each exchange kept only where the "
        "depth agrees) and with --online (read forwards; the depth judges each exchange "
        "before its poses are published), off with --per-frame",
    )  # fmt: skip
    sides.add_argument(
        "--no-fix-sides", dest="fix_sides", action="store_const", const=False,
        help="take the detector's left/right labels as they come",
    )  # fmt: skip
    t.add_argument(
        "--keep-duplicates", action="store_true",
        help="fit a keypoint detection that jumped onto another keypoint as given (default: "
        "dropped while it stays there, offline and with --online; never with --per-frame)",
    )  # fmt: skip
    t.add_argument(
        "--frame", choices=("camera", "floor"), default="camera",
        help="frame of the poses, JSON, BVH and TRC: the depth camera's (x right, y down, z "
        "forward) or the floor's (y up, metres, origin on the floor under the first tracked "
        "pelvis; needs a visible floor) (default: %(default)s)",
    )  # fmt: skip
    _add_video_options(t)
    t.add_argument("--seed", type=int, default=0, help="random seed of the hypotheses")
    t.add_argument("--quiet", action="store_true", help="no progress bars")
    t.add_argument(
        "--out", required=True, metavar="DIR", help="output folder (replaced as a whole)"
    )
    t.set_defaults(func=_track)

    m = sub.add_parser(
        "track-many",
        help="track every recording of a manifest (CSV), several at a time, resumably",
        description="Track every recording listed in a manifest: CSV with a header row and "
        "columns name,depth,keypoints,intrinsics (optional: rgb, depth_scale); relative paths "
        "are relative to the manifest's folder. Each recording's files (those of `posetrack "
        "track`) go to DIR/<name>/, written atomically when it is done; DIR/summary.json lists "
        "every recording as done, failed (with the error) or pending. Re-running over the same "
        "DIR skips the recordings already done. --batch recordings run side by side, their "
        "tracker steps batched into one compiled call per frame.",
        epilog="Exit codes: 0 all done, 2 bad manifest or arguments (one 'error:' line, "
        "nothing tracked) or some recordings failed (listed in DIR/summary.json), 1 system "
        "error, 130 interrupted (finished recordings are kept).",
    )  # fmt: skip
    m.add_argument("--manifest", required=True, metavar="FILE.csv", help="the recordings")
    m.add_argument("--out", required=True, metavar="DIR", help="output folder (DIR/<name>/)")
    m.add_argument(
        "--batch", type=int, default=8, metavar="B",
        help="recordings tracked side by side (default: %(default)s)",
    )  # fmt: skip
    _add_method_options(m)
    _add_mode_options(m)
    _add_passes_options(m)
    _add_video_options(m)
    m.add_argument("--seed", type=int, default=0, help="random seed of the hypotheses")
    m.add_argument("--quiet", action="store_true", help="no progress bar")
    m.add_argument(
        "--num-processes", type=int, metavar="P",
        help="processes sharing the manifest (jax.distributed; with --process-id and "
        "--coordinator)",
    )  # fmt: skip
    m.add_argument("--process-id", type=int, metavar="I", help="this process, 0..P-1")
    m.add_argument(
        "--coordinator", metavar="HOST:PORT",
        help="address of process 0's coordinator (jax.distributed.initialize)",
    )  # fmt: skip
    m.set_defaults(func=_track_many)

    w = sub.add_parser(
        "warmup",
        help="compile the tracker for a configuration into the cache ahead of time",
        description="Compile the tracker's programs for one configuration and depth size into "
        "the cache (POSETRACK_CACHE_DIR, default ~/.cache/posetrack), e.g. in a Docker build, "
        "so that the first `posetrack track` with that configuration starts in seconds. The "
        "options mean what they mean for `posetrack track`; the camera's focal length does "
        "not matter, its image size does.",
    )  # fmt: skip
    w.add_argument(
        "--intrinsics", metavar="FILE",
        help="the depth camera's intrinsics file (as for track; it must give the image size)",
    )  # fmt: skip
    w.add_argument("--size", type=_size_arg, metavar="WxH", help="or only its image size")
    _add_method_options(w)
    _add_mode_options(w)
    w.set_defaults(func=_warmup)
    return p


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit code (0 ok, 1 system error, 2 bad input,
    130 interrupted)."""
    args = build_parser().parse_args(argv)
    from .._programs import enable_cache

    enable_cache()  # POSETRACK_CACHE_DIR, default ~/.cache/posetrack; "off" disables it
    if os.environ.get("POSETRACK_TRACEBACK"):
        return args.func(args)
    try:
        return args.func(args)
    except KeyboardInterrupt:
        # The progress bar may have left the cursor mid-line.
        if args.command == "track-many":
            print("\ninterrupted: the recordings already done are kept; run the same command "
                  "again to track the rest", file=sys.stderr)  # fmt: skip
        else:
            print("\ninterrupted: nothing was written (outputs appear only when complete)",
                  file=sys.stderr)  # fmt: skip
        return 130
    except (ValueError, FileExistsError) as e:  # InputError is a ValueError
        print(f"error: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # disk full, permissions: not the input's fault, still no traceback
        print(f"error: {_os_error_text(e)}", file=sys.stderr)
        return 1


def _os_error_text(e: OSError) -> str:
    """``e`` as one line without Python's ``[Errno N]`` prefix: "PATH: reason", or the
    sentence the code raised (``OSError(errno, sentence)`` or ``OSError(sentence)``)."""
    if e.strerror is None:
        return str(e)
    text = e.strerror if e.filename is None else f"{os.fsdecode(e.filename)}: {e.strerror}"
    if e.filename2 is not None:
        text += f" (-> {os.fsdecode(e.filename2)})"
    return " ".join(text.split())  # one line, whatever the message held


if __name__ == "__main__":
    sys.exit(main())
