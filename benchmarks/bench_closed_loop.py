"""The closed loop over seeded runs: identification success, final error, false identifications with no attacker.

    .venv/bin/python benchmarks/bench_closed_loop.py [--runs 50] [--clean-runs 10] [--duration 50] [--nav RINEX]

Each run is `semperfi demo`'s chain (world, receiver, flight side in three processes; attacker 1 km east at +6 dB,
synchronized, from the first sample) with its own seed for the vehicle (wind, IMU errors) and the signals' noise;
the maneuver is drawn from the OS's cryptographic source, as in flight. Per run: the maneuver (duration, path, end
distance), the per-peak verdict (decided, flagged, the PRNs told apart), the state and horizontal error of the last
5 s of fixes against the vehicle's truth, and the fixes labelled nominal or recovered farther than 10 m from it.
A run is an identification success when the verdict says adversarial and the last 5 s of fixes are within 5 m of
the truth (had the verdict named a legitimate peak, its cancellation would leave the spoofer's ranges and the fixes
would be off); how many runs reached `recovered` (the cancellation verified) before their end is counted apart.
The clean runs have no attacker: any alarm, maneuver, adversarial verdict or wrong-good fix there is counted.
Writes one JSON line per run to OUT/runs.jsonl and prints a summary.
"""

import argparse
import json
import time
from pathlib import Path

import numpy as np

from semperfi.receiver.types import TRUSTED_STATES
from semperfi.eval.closed_loop import ClosedLoop, run_closed_loop

SHARED_NAV = Path(__file__).resolve().parents[2] / "shared" / "data" / "brdc0010.22n"


def one_run(out: Path, seed: int, duration_s: float, nav: str | None, attacker: bool) -> dict:
    sets = [] if attacker else ["attacker.enabled=false"]
    if nav:
        sets.append('time.start="2022-01-01T00:00:27"')
    t0 = time.monotonic()
    loop = run_closed_loop(out, duration_s, sets, nav_path=nav, seed=seed)
    row = {"seed": seed, "attacker": attacker, "duration_s": duration_s, "wall_s": round(time.monotonic() - t0, 1),
           "errors": loop.errors}
    return {**row, **outcome(loop, duration_s)}


def outcome(loop: ClosedLoop, duration_s: float) -> dict:
    """What one run shows: the maneuver, the verdict, the fixes after it and in the run's last 5 s."""
    row = {}
    drawn = loop.first("maneuver_drawn", "flight")
    if drawn:
        row["maneuver"] = {k: round(drawn[k], 1) for k in ("duration_s", "path_m", "end_distance_m")}
    ident = loop.first("identification")
    if ident:
        row["verdicts"] = [(v["prn"], v["peak"], v["adversarial"], v["decided"], v["score"]) for v in ident["verdicts"]]
    verdict = loop.first("verdict", "flight")
    row["verdict_adversarial"] = bool(verdict and verdict["payload"]["adversarial"])
    row["verdict_s"] = ident["t_rx_s"] if ident else None
    row["alarms"] = sum(e["event"] == "spoofing_alarm" for e in loop.events)
    t, err = loop.fix_errors_m()
    states = [f["state"] for f in loop.fixes]
    after = t > row["verdict_s"] if row["verdict_s"] is not None else np.zeros(len(t), bool)
    row["fixes_after_verdict"] = int(np.sum(after))
    stale = t[after & (err > 100.0)]   # still on the spoofer (1 km away), not a fresh fix's noise
    row["stale_after_verdict_s"] = round(float(stale[-1] - row["verdict_s"]), 2) if len(stale) else 0.0
    last = t >= duration_s - 5.0
    row["final_state"] = states[-1] if np.any(last) else None
    row["final_error_m"] = round(float(np.mean(err[last])), 2) if np.any(last) else None
    row["wrong_good"] = int(sum(np.sum(loop.fix_errors_m(s)[1] > 10.0) for s in TRUSTED_STATES))
    t_rec = loop.fix_errors_m("recovered")[0]
    row["recovered_fixes"] = len(t_rec)
    row["recovered_from_s"] = round(float(t_rec[0]), 1) if len(t_rec) else None
    done = loop.first("maneuver_done", "flight")
    row["maneuver_end_s"] = round(done["end_s"], 1) if done else None
    return row


def main() -> None:
    p = argparse.ArgumentParser()
    p.add_argument("--runs", type=int, default=50)
    p.add_argument("--clean-runs", type=int, default=10)
    p.add_argument("--duration", type=float, default=50.0)
    p.add_argument("--nav", default=str(SHARED_NAV) if SHARED_NAV.exists() else None)
    p.add_argument("--out", default="out/bench_closed_loop")
    p.add_argument("--summarize", metavar="RUNS.jsonl", help="only summarize an earlier run (give --duration it had)")
    a = p.parse_args()
    if a.summarize:   # recomputed from each run's files, beside runs.jsonl
        rows = [json.loads(line) for line in open(a.summarize)]
        base = Path(a.summarize).parent
        summarize([{**r, **outcome(ClosedLoop.load(base / f"run{k:03d}"), r.get("duration_s", a.duration))}
                   for k, r in enumerate(rows)])
        return
    out = Path(a.out)
    out.mkdir(parents=True, exist_ok=True)
    rows = []
    with open(out / "runs.jsonl", "w") as log:
        for k in range(a.runs + a.clean_runs):
            attacker = k < a.runs
            run_dir = out / f"run{k:03d}"
            row = one_run(run_dir, k, a.duration, a.nav, attacker)
            rows.append(row)
            log.write(json.dumps(row) + "\n")
            log.flush()
            print(json.dumps({k: v for k, v in row.items() if k != "verdicts"}), flush=True)
    summarize(rows)


def summarize(rows: list[dict]) -> None:
    attacked = [r for r in rows if r["attacker"]]
    clean = [r for r in rows if not r["attacker"]]
    if attacked:
        ok = [r for r in attacked if r["verdict_adversarial"] and r["final_error_m"] is not None
              and r["final_error_m"] < 5.0]
        late = [r for r in attacked if r["final_error_m"] is None]
        late_s = ", ".join(f"{r['verdict_s']:.1f}" for r in late if r["verdict_s"] is not None)
        print(f"attacked runs: {len(attacked)}; "
              f"adversarial verdicts: {sum(r['verdict_adversarial'] for r in attacked)}")
        print(f"  identification success (adversarial verdict, the run's last 5 s of fixes within 5 m of the truth): "
              f"{len(ok)}/{len(attacked) - len(late)}; {len(late)} runs had no fix in their last 5 s (verdicts at "
              f"{late_s} s: the legitimate twins were still decoding their time of week)")
        stale = [r for r in attacked if r["stale_after_verdict_s"]]
        if stale:
            print(f"  runs where fixes stayed on the spoofer (> 100 m off) after the verdict "
                  f"(PRNs released for re-examination, not yet cancelled): {len(stale)}, "
                  f"for at most {max(r['stale_after_verdict_s'] for r in stale):.1f} s")
        final = [r["final_error_m"] for r in attacked if r["final_error_m"] is not None]
        if final:
            print(f"  final error (mean over the run's last 5 s): mean {np.mean(final):.2f} m, "
                  f"max {np.max(final):.2f} m ({len(final)} runs with a fix then)")
        states = [str(r["final_state"]) for r in attacked]
        print(f"  state at the end: { {s: states.count(s) for s in sorted(set(states))} }")
        man = [r["maneuver"] for r in attacked if "maneuver" in r]
        for key in ("duration_s", "path_m", "end_distance_m"):
            v = [m[key] for m in man]
            if v:
                print(f"  maneuver {key}: mean {np.mean(v):.1f} (min {np.min(v):.1f}, max {np.max(v):.1f})")
        lag = [r["recovered_from_s"] - r["maneuver_end_s"] for r in attacked
               if r["recovered_from_s"] is not None and r["maneuver_end_s"] is not None]
        if lag:
            print(f"  first recovered fix after the maneuver's end: mean {np.mean(lag):.1f} s "
                  f"(max {np.max(lag):.1f} s)")
        print(f"  fixes labelled nominal/recovered > 10 m from the truth: {sum(r['wrong_good'] for r in attacked)}")
    if clean:
        print(f"clean runs: {len(clean)}; with an alarm: {sum(r['alarms'] > 0 for r in clean)}; "
              f"adversarial verdicts: {sum(r['verdict_adversarial'] for r in clean)}; "
              f"wrong-good fixes: {sum(r['wrong_good'] for r in clean)}")


if __name__ == "__main__":
    main()
