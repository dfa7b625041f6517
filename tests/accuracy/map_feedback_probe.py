"""What the map's registrations do to the graph: each one against the ground truth (session 9).

    PYTHONPATH=. python tests/accuracy/map_feedback_probe.py ROW MODE OUT [frames=N] [key=value ...]

Runs a row of ``gsslam/run/suites/tracking.yaml`` in process with the defaults (map and loops on; the
map's final pass off: it is map-only, the trajectory does not depend on it) plus the overrides, and
records every registration the map stage makes (:meth:`gsslam.slam.map_stage.MapStage._register`):
the graph's pose of the keyframe at that moment, the registered pose, its information, coverage,
converged share and whether it was gated. After the run both poses are brought into the ground
truth's frame by the alignment of the final trajectory (Sim(3) in mono, SE(3) in RGB-D) and compared
with the keyframe's ground truth: did the registration move the keyframe towards it or away? Prints
ATE and one JSON line per registration; writes ``OUT.json``. Not a test: a measuring tool
(docs/results.md, "The map's effect on the trajectory, session 9").

Session 10 adds: the registrations withheld (``mapper.registration_unconverged_weight=0``) and whether
each one moved the pose; whether the graph moved a keyframe between its registration and the sending
(it should not: both happen in one map step); and staleness: where the map's keyframes were when a
registration was measured and at the end of the run, the registration carried along with the nearest
one's motion ("re-expressed") against the ground truth (docs/results.md, "Mono map registrations,
session 10").
"""

from __future__ import annotations

import json
import logging
import sys
from pathlib import Path

import numpy as np
import yaml

import gsslam.slam.map_stage as MS
from gsslam.config import load_config
from gsslam.datasets.base import open_dataset
from gsslam.eval.align import align_positions
from gsslam.geometry import invert_T, so3_log, split_sim3
from gsslam.io.trajectory import read_tum, write_tum
from gsslam.run.run_metrics import evaluate_run
from gsslam.run.sequence import run_sequence

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / ".." / "shared" / "data"


def _row(name: str, mode: str) -> dict:
    suite = yaml.safe_load((ROOT / "gsslam" / "run" / "suites" / "tracking.yaml").read_text())
    for row in suite["sequences"]:
        modes = row["mode"] if isinstance(row["mode"], list) else [row["mode"]]
        if row["name"] == name and mode in modes:
            return row
    raise SystemExit(f"no row {name!r} ({mode}) in the tracking suite")


def _rigid(T: np.ndarray) -> np.ndarray:
    R, t, _ = split_sim3(np.asarray(T, dtype=np.float64))
    out = np.eye(4)
    out[:3, :3], out[:3, 3] = R, t
    return out


def main(name: str, mode: str, out: str, *overrides: str) -> None:
    logging.basicConfig(level=logging.WARNING)
    row = _row(name, mode)
    frames = row.get("frames")
    if overrides and overrides[0].startswith("frames="):  # a shorter prefix of the row
        frames, overrides = int(overrides[0].split("=")[1]), overrides[1:]
    cfg = load_config(None, ["mapper.final_iterations_per_keyframe=0", *overrides], mode=mode)
    recs: list[dict] = []
    orig = MS.MapStage._register

    def recorded(self, chains, cid, sid, enc, by_index, new_keyframes):
        chains_seen[:] = [chains]
        res = orig(self, chains, cid, sid, enc, by_index, new_keyframes)
        sent = {int(reg.index): reg for _, reg in res}
        held = {int(reg.index): reg for reg in getattr(self, "withheld", [])}  # not at the map's minimum
        for idx in new_keyframes:
            pos = list(enc.frame_indices).index(idx)
            T = self._submap_pose(chains[cid], sid) @ enc.T_local_cam[pos]
            f = by_index[idx]
            d = dict(index=int(idx), ts=float(f.timestamp), T_graph=_rigid(T).tolist(), sent=idx in sent)
            d["withheld"] = idx in held
            d["scale"] = float(split_sim3(T)[2])
            if f.T_world_cam_gt is not None:
                d["T_gt"] = np.asarray(f.T_world_cam_gt).tolist()
            if idx in sent or idx in held:
                r = sent.get(idx) or held[idx]
                d.update(T_reg=r.T_world_cam.tolist(), info=r.information.tolist(), coverage=r.coverage)
                d.update(residual=r.residual, min_information=r.min_information, converged=r.converged)
                d.update(outcome=getattr(r, "at_minimum", None), sent_scale=getattr(r, "weight", 1.0))
                # the map's keyframes where the graph had them when this one was measured (staleness)
                d["map_at"] = {int(i): _rigid(self._keyframe_pose(chains, i)).tolist() for i in self._anchor}
            recs.append(d)
        return res

    orig_final = MS.MapStage.finalize

    def final_poses(self, chains, *a, **k):  # the map's keyframes at the end (after the batch refinement)
        final.update({int(i): _rigid(self._keyframe_pose(chains, i)).tolist() for i in self._anchor})
        return orig_final(self, chains, *a, **k)

    final: dict[int, list] = {}
    MS.MapStage.finalize = final_poses
    orig_send = MS.MapStage.send_registrations
    chains_seen: list = []

    def sent_at(self, chain, sid):  # did the graph move the keyframe between measuring and sending?
        by = {d["index"]: d for d in recs if d["sent"]}
        for _, reg in self.pending:
            d = by.get(int(reg.index))
            if d is not None and int(reg.index) in self._anchor:
                T = _rigid(self._keyframe_pose(chains_seen[0], int(reg.index)))
                d["moved_before_send_m"] = float(np.linalg.norm(T[:3, 3] - np.array(d["T_graph"])[:3, 3]))
        return orig_send(self, chain, sid)

    MS.MapStage.send_registrations = sent_at

    MS.MapStage._register = recorded
    kw = dict(row.get("kwargs") or {})
    res = run_sequence(
        DATA / row["path"], row["dataset"], cfg, out, max_frames=frames, progress=False,
        overwrite=True, **kw,
    )  # fmt: skip
    MS.MapStage._register = orig
    MS.MapStage.finalize = orig_final
    MS.MapStage.send_registrations = orig_send
    for d in recs:
        d["final"] = final.get(d["index"])
        if "map_at" in d:  # the final poses of the map's keyframes that were in it at the time
            d["map_final"] = {i: final[i] for i in d["map_at"] if i in final}
    Path(out + ".records.json").write_text(json.dumps(recs))  # before anything else can fail
    gt_kw = dict(kw, with_depth=False) if mode == "mono" and row["dataset"] == "tum" else kw
    write_tum(
        open_dataset(row["dataset"], DATA / row["path"], **gt_kw).ground_truth(),
        Path(out) / "groundtruth.tum",
    )
    print(
        json.dumps(
            {
                k: evaluate_run(Path(out)).get(k)
                for k in ("ate_m", "ate_kf_m", "sim3_scale", "rpe_t_m", "rpe_r_deg")
            }
        )
    )
    ate = 100 * (res.metrics["ate"] or {}).get("rmse_m", float("nan"))
    ate_kf = 100 * (res.metrics["ate_keyframes"] or {}).get("rmse_m", float("nan"))
    print(f"{name} {mode} {' '.join(overrides)}: ATE {ate:.3f} cm, kf {ate_kf:.3f}; "
          f"registrations {sum(r['sent'] for r in recs)} sent of {len(recs)}")  # fmt: skip
    analyse(out, mode, recs, res.metrics)


def _staleness(d: dict, R: np.ndarray, err, s: float) -> dict:
    """How far the map moved under a registration after it was measured: the map's keyframes nearest to
    the registered pose (5, already in the map then), their poses then and at the end of the run; the
    registration carried along with the nearest one's rigid motion ("re-expressed") against the ground
    truth, and the keyframe's final pose against the registered one."""
    if not d.get("map_at") or not d.get("map_final"):
        return {}
    at = {int(i): np.array(T) for i, T in d["map_at"].items()}
    fin = {int(i): np.array(T) for i, T in d["map_final"].items()}
    common = [i for i in at if i in fin]
    if not common:
        return {}
    near = sorted(common, key=lambda i: float(np.linalg.norm(at[i][:3, 3] - R[:3, 3])))[:5]
    moved = np.mean([fin[i][:3, 3] - at[i][:3, 3] for i in near], axis=0)
    M = fin[near[0]] @ invert_T(at[near[0]])  # the nearest map keyframe's motion since (world frame)
    out = dict(map_moved_cm=round(100 * s * float(np.linalg.norm(moved)), 2))
    out["reexpressed_cm"] = round(err(M @ R)[0], 2)
    if d.get("final") is not None:
        F = np.array(d["final"])
        out["final_cm"] = round(err(F)[0], 2)
        out["reg_to_final_cm"] = round(100 * s * float(np.linalg.norm(F[:3, 3] - R[:3, 3])), 2)
    return out


def _med(xs: list[dict], key: str) -> float:
    return float(np.median([x[key] for x in xs]))


def _summarise(summary: list[dict], recs: list[dict]) -> None:
    """Moved or not, towards the ground truth or away; how stale the registrations got."""
    for sent, moved in ((True, True), (True, False), (False, True), (False, False)):
        xs = [x for x in summary if x["moved"] == moved and x.get("sent", True) == sent]
        if xs:
            tw = sum(x["reg_cm"] < x["graph_cm"] for x in xs)
            aw = sum(x["reg_cm"] > x["graph_cm"] for x in xs)
            what = f"{'sent' if sent else 'withheld'}, {'moved' if moved else 'did not move'}"
            print(f"{what}: {len(xs)}, towards the ground truth {tw}, away {aw}; median graph "
                  f"{_med(xs, 'graph_cm'):.2f} cm, registered {_med(xs, 'reg_cm'):.2f} cm")  # fmt: skip
    mb = [d["moved_before_send_m"] for d in recs if "moved_before_send_m" in d]
    if mb:
        n = sum(m > 1e-9 for m in mb)
        print(f"graph moved the keyframe between measuring and sending: {n} of {len(mb)} "
              f"(max {max(mb):.2e} world units)")  # fmt: skip
    st = [x for x in summary if "map_moved_cm" in x]
    if st:
        mm = np.array([x["map_moved_cm"] for x in st])
        print(f"map moved under the registration after it was measured: median {np.median(mm):.2f} cm, "
              f"> 0.5 cm: {int((mm > 0.5).sum())} of {len(st)}; registered {_med(st, 'reg_cm'):.2f} cm, "
              f"re-expressed {_med(st, 'reexpressed_cm'):.2f} cm (median against the ground truth)")  # fmt: skip


def analyse(out: str, mode: str, recs: list[dict], metrics: dict) -> None:
    """Each sent registration and the graph's pose against the ground truth, in its frame."""
    est, gt = read_tum(Path(out) / "trajectory.tum"), read_tum(Path(out) / "groundtruth.tum")
    tg = np.asarray(gt.timestamps, dtype=np.float64)  # nearest ground truth within 20 ms (TUM: mocap)
    pairs = []
    for t, p in zip(est.timestamps, est.poses):
        j = int(np.argmin(np.abs(tg - t)))
        if abs(tg[j] - t) < 0.02:
            pairs.append((p, gt.poses[j]))
    A = align_positions(np.array([b[:3, 3] for _, b in pairs]), np.array([a[:3, 3] for a, _ in pairs]),
                        "sim3" if mode == "mono" else "se3")  # fmt: skip
    S = A.matrix
    s = float(np.cbrt(np.linalg.det(S[:3, :3])))
    summary = []
    for d in recs:
        if "T_reg" not in d or "T_gt" not in d:
            continue
        G, R, Tgt = np.array(d["T_graph"]), np.array(d["T_reg"]), np.array(d["T_gt"])

        def err(T, Tgt=Tgt):  # -> (cm, deg) of the pose against the ground truth, in its frame
            p = S[:3, :3] @ T[:3, 3] + S[:3, 3]
            Rw = S[:3, :3] / s @ T[:3, :3]
            deg = float(np.degrees(np.linalg.norm(so3_log(Tgt[:3, :3].T @ Rw))))
            return 100 * float(np.linalg.norm(p - Tgt[:3, 3])), deg

        D = invert_T(G) @ R  # the registration's step from the graph's pose (right perturbation)
        xi = np.r_[so3_log(D[:3, :3]), D[:3, 3]]  # (phi, rho)
        maha = float(xi @ np.array(d["info"]) @ xi)
        eg, er = err(G), err(R)
        line = dict(index=d["index"], graph_cm=round(eg[0], 2), reg_cm=round(er[0], 2),
                    graph_deg=round(eg[1], 2), reg_deg=round(er[1], 2),
                    step_cm=round(100 * s * float(np.linalg.norm(D[:3, 3])), 2),
                    step_deg=round(float(np.degrees(np.linalg.norm(xi[:3]))), 2), maha=round(maha, 2),
                    coverage=round(d["coverage"], 2), residual=round(d["residual"], 3),
                    converged=round(d["converged"], 2), min_info=round(d["min_information"], 0))  # fmt: skip
        line.update(sent=d["sent"], moved=bool(np.abs(xi).max() > 1e-9), outcome=d.get("outcome"))
        line["weight"] = d.get("sent_scale")
        line.update(_staleness(d, R, err, s))
        summary.append(line)
        print(json.dumps(line))
    _summarise(summary, recs)
    summary_sent = [x for x in summary if x.get("sent", True)]
    if summary_sent:
        better = sum(x["reg_cm"] < x["graph_cm"] for x in summary_sent)
        print(f"sent registrations closer to the ground truth than the graph's pose: {better} of "
              f"{len(summary_sent)}; median graph {_med(summary_sent, 'graph_cm'):.2f} cm, "
              f"registered {_med(summary_sent, 'reg_cm'):.2f} cm")  # fmt: skip
    keep = {k: metrics.get(k) for k in ("ate", "ate_keyframes")}
    Path(out + ".json").write_text(
        json.dumps(dict(metrics=keep, scale=s, registrations=summary, records=recs))
    )


if __name__ == "__main__":
    if sys.argv[1] == "analyse":  # again from OUT.records.json and the run folder: analyse OUT MODE
        o = sys.argv[2]
        analyse(
            o,
            sys.argv[3],
            json.loads(Path(o + ".records.json").read_text()),
            json.loads((Path(o) / "metrics.json").read_text()),
        )
    else:
        main(*sys.argv[1:])
