"""What the offline left/right arbitration's decisions cost (issue 12, a diagnosis).

Offline (``Tracker(mode="offline")``) each stretch the two-sided left/right reading reads
exchanged is tracked twice from the same state, with the labels exchanged and as detected,
and the reading whose per-frame poses score the lower Delta (Eq. (3)) summed over the
stretch is kept (``posetrack._sides.prefer_exchanged``). This records, for every stretch of
the shipped offline tracker on wide real-motion tuning clips, both readings' Delta and their
per-frame poses' error against the truth (D over the 13 body joints, mm), and asks how much
D the decision gives away against an oracle that keeps the reading nearer the truth, for the
shipped rule (the Delta summed over the whole stretch) and for other rules one could write
from the same numbers: the Delta summed over the stretch's first k frames only (where a
wrong labelling drags the limbs across the body), over its first k and its last frames
after the exchanged run (where the labels come back), the sign of most frames' difference,
and the median difference.

The loss is counted where it is made, over the stretch's own frames (the tracking after the
stretch follows whichever reading was kept, so its later frames are not compared). Each rule
keeps the shipped rule's condition that a reading which estimated fewer frames (it lost the
track) does not win. Nothing in the tracker is chosen here.

Tuning seeds only; wide real motion (``tune.real_motion``), clean and occluded (level 2),
120 frames at 30 fps, 320x240, tracker seed 0.

    python benchmarks/arbitration.py --seeds 1536-1559 --part 0 --parts 2 --out a.json
    python benchmarks/arbitration.py --merge a.json b.json --out results/arbitration.json
"""

from __future__ import annotations

import numpy as np
from judge import detections_exchanged
from tune import diagnosis_runs, write_diagnosis

import posetrack as pt

#: COCO-18 body joints D is measured on (neck to ankles), as ``decide.py``'s D.
BODY = list(range(1, 14))


class _Recording(pt.Tracker):
    """The shipped tracker, recording each arbitrated stretch's two readings (the Delta and
    the poses of their frames, the two-sided reading's exchanged frames)."""

    def _reading(self, start, stop, out, frames, progress, mask):
        delta = super()._reading(start, stop, out, frames, progress, mask)
        self._readings.append((delta.copy(), out.kp3[start:stop].copy()))
        return delta

    def _arbitrate_span(self, start, stop, out, kept, frames, progress):
        self._readings = []
        read = self._two_sided[1][start:stop].any(axis=1)
        end = super()._arbitrate_span(start, stop, out, kept, frames, progress)
        (delta_ex, kp_ex), (delta_as, kp_as) = self._readings[:2]  # exchanged, then detected
        self.recorded.append((start, stop, read, delta_ex, kp_ex, delta_as, kp_as))
        return end


def _errors(kp: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per frame, the mean error (mm) of the body joints; NaN where the frame has no pose."""
    return np.linalg.norm(kp[:, BODY] - truth[:, BODY], axis=-1).mean(axis=1) * 1000


def run_clip(seq) -> dict:
    tr = _Recording(seq.intrinsics, mode="offline", seed=0)
    tr.recorded = []
    res = tr.run(seq.depth, seq.keypoints2d, seq.confidence)
    det = detections_exchanged(seq).any(axis=1)
    spans = []
    for (start, stop, read, delta_ex, kp_ex, delta_as, kp_as), entry, groups in zip(
        tr.recorded, tr.side_spans, tr.side_span_groups, strict=True
    ):
        truth = seq.joints3d[start:stop]
        spans.append({
            "start": int(start), "stop": int(stop), "groups": np.asarray(groups).tolist(),
            "kept": bool(entry[4]), "read_exchanged": np.asarray(read).tolist(),
            "detections_exchanged": det[start:stop].tolist(),
            "delta_exchanged": delta_ex.tolist(), "delta_detected": delta_as.tolist(),
            "error_exchanged_mm": _errors(kp_ex, truth).tolist(),
            "error_detected_mm": _errors(kp_as, truth).tolist(),
        })  # fmt: skip
    return {
        "D_mm": pt.accuracy(res.keypoints3d, seq.joints3d).mean_mm,
        "swapped_limb_frames": pt.swapped_limb_frames(res.keypoints3d, seq.joints3d),
        "spans": spans,
    }


def _sum_over(selected):
    """A rule: the exchanged reading's Delta minus the detected one's, summed over the frames
    ``selected(n, read)`` picks (``n`` frames; ``read``: the two-sided reading's exchanged
    frames) that both readings estimated. Negative: keep the exchange."""

    def rule(dex: np.ndarray, das: np.ndarray, read: np.ndarray) -> float:
        both = np.isfinite(dex) & np.isfinite(das) & selected(len(dex), read)
        return float((dex[both] - das[both]).sum()) if both.any() else 0.0

    return rule


def _first(k: int):
    return _sum_over(lambda n, read: np.arange(n) < k)


def _ends(k: int):
    def pick(n, read):
        last = np.flatnonzero(read).max() if read.any() else n
        return (np.arange(n) < k) | (np.arange(n) > last)

    return _sum_over(pick)


def _majority(dex, das, read) -> float:
    d = (dex - das)[np.isfinite(dex - das)]
    return float((d > 0).sum() - (d < 0).sum()) - 0.5  # a tie keeps the detections


def _median(dex, das, read) -> float:
    d = (dex - das)[np.isfinite(dex - das)]
    return float(np.median(d)) if len(d) else 0.0


#: The rules compared (name -> score; the exchange is kept where the score is < 0).
RULES = {
    "whole stretch (shipped)": _sum_over(lambda n, read: np.ones(n, bool)),
    **{f"first {k} frames": _first(k) for k in (2, 4, 6, 8, 12)},
    **{f"first {k} + after the run": _ends(k) for k in (2, 4, 6)},
    "most frames": _majority,
    "median frame": _median,
}


def rule_table(runs: list[dict]) -> dict:
    """Per rule: the D (mm, summed over the stretches' frames both readings estimated)
    given away against the oracle, as metres x frames and as mm of the runs' mean D, and how
    many stretches it decides wrongly by more than 10 mm a frame."""
    frames = 120 * len(runs)
    table = {}
    for name, rule in RULES.items():
        lost, wrong = 0.0, 0
        for run in runs:
            for s in run["spans"]:
                dex, das = (np.asarray(s[k], float) for k in ("delta_exchanged", "delta_detected"))
                eex, eas = (np.asarray(s[k], float) for k in ("error_exchanged_mm",
                                                              "error_detected_mm"))  # fmt: skip
                ok = np.isfinite(eex) & np.isfinite(eas)
                if not ok.any():
                    continue
                keep = rule(dex, das, np.asarray(s["read_exchanged"])) < 0
                keep &= np.isfinite(dex).sum() >= np.isfinite(das).sum()
                ex, ad = eex[ok].sum(), eas[ok].sum()
                chosen, other = (ex, ad) if keep else (ad, ex)
                lost += max(chosen - other, 0.0)
                wrong += chosen - other > 10.0 * ok.sum()
        table[name] = {"lost_m_frames": lost / 1000, "lost_mm_of_mean_D": lost / frames,
                       "wrong_by_10mm": int(wrong)}  # fmt: skip
    return table


def main() -> int:
    a, runs = diagnosis_runs(__doc__, "1536-1559", "arbitration", run_clip)
    n = sum(len(r["spans"]) for r in runs)
    print(f"\nOffline left/right arbitration, {n} stretches in {len(runs)} wide real tuning runs")
    print(f"{'rule':28s} {'lost (m x frames)':>18s} {'mm of mean D':>13s} {'wrong by >10 mm':>16s}")
    table = rule_table(runs)
    for name, row in table.items():
        print(f"{name:28s} {row['lost_m_frames']:18.2f} {row['lost_mm_of_mean_D']:13.2f} "
              f"{row['wrong_by_10mm']:16d}")  # fmt: skip
    shipped = [s["kept"] for r in runs for s in r["spans"]]
    print(f"kept exchanges: {sum(shipped)} of {len(shipped)}")
    write_diagnosis(a.out, "arbitration", table, runs, stretches=n)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
