"""The paper's task allocation under attack: does the signed swarm do exactly what it does
without the attacker, and what do signatures cost the simulator?

    python bench/attack_sim.py [--drops 0,0.5] [--runs 5] [--robots 6] [--seconds 120]
        [--out DIR]

Each run is a cell of `fieldkit sim experiment task-allocation` (its commands, task graph
and seeds: run k has seed k), simulated four ways in one process:

* `none`: ROSBuzz's plain bundles (the experiment as published);
* `signed`: every bundle sealed and checked (issue 15);
* `signed+attack`: signed, with a hostile radio in the swarm's middle doing all of
  replay, forge, command and flood (fieldkit/sim/attacker.py);
* `none+attack`: the same attacker against the plain swarm.

Reported per run: whether `signed+attack` ended exactly as `signed` did (every robot's
final state and position, the log, the radio's delivery count), `accepted_from_attacker`
for both attacked swarms, what the signed swarm rejected per reason, the bytes per bundle on
the air (plain and signed), and the wall time of each variant. The ratios signed/none and
signed+attack/signed are what carry to other machines, not the seconds. Writes
DIR/summary.json (default docs/results/attack) and prints a table.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import logging
import time
from pathlib import Path

from cryptography.hazmat.primitives.asymmetric.ed25519 import Ed25519PrivateKey

from fieldkit.sim.attacker import ATTACKS
from fieldkit.sim.experiments import make_plan
from fieldkit.sim.simulator import SimConfig, Simulation

SWARM_KEY = bytes(range(32))
OPERATOR = Ed25519PrivateKey.from_private_bytes(bytes(range(32, 64)))


def simulate(config: SimConfig) -> tuple[Simulation, float]:
    """The finished simulation of `config` and its wall time in seconds."""
    t0 = time.perf_counter()
    sim = Simulation(config)
    sim.run()
    return sim, time.perf_counter() - t0


def outcome(sim: Simulation) -> tuple[object, ...]:
    """What the swarm did: final states, positions, the log, the deliveries."""
    where = {r.id: (r.vehicle.x, r.vehicle.y, r.vehicle.z) for r in sim.robots.values()}
    return sim.summary()["final_states"], where, sim.log, sim.radio.delivered


def one_run(base: SimConfig) -> dict[str, object]:
    """The four variants of one cell's run."""
    keyed = dataclasses.replace(base, swarm_key=SWARM_KEY, operator_pub=OPERATOR.public_key())
    variants = {
        "none": dataclasses.replace(keyed, security="none"),
        "signed": dataclasses.replace(keyed, security="signed"),
        "signed+attack": dataclasses.replace(keyed, security="signed", attacks=ATTACKS),
        "none+attack": dataclasses.replace(keyed, security="none", attacks=ATTACKS),
    }
    sims: dict[str, Simulation] = {}
    wall: dict[str, float] = {}
    for name, config in variants.items():
        sims[name], wall[name] = simulate(config)
    summaries = {name: sim.summary() for name, sim in sims.items()}
    signed_sec = summaries["signed+attack"]["security"]
    plain_sec = summaries["none+attack"]["security"]
    assert isinstance(signed_sec, dict) and isinstance(plain_sec, dict)
    return {
        "seed": base.seed,
        "drop": base.drop,
        "unchanged_by_attack": outcome(sims["signed+attack"]) == outcome(sims["signed"]),
        "final_states": summaries["signed"]["final_states"],
        "accepted_from_attacker": {
            "signed": signed_sec["accepted_from_attacker"],
            "none": plain_sec["accepted_from_attacker"],
        },
        "plain_swarm_changed_by_attack": outcome(sims["none+attack"]) != outcome(sims["none"]),
        "rejected": signed_sec["rejected"],
        "commands": signed_sec.get("commands", {}),
        "attacker_sent": signed_sec["attacker"]["sent"],  # type: ignore[index]
        "mean_bundle_air_bytes": {
            "none": summaries["none"]["mean_bundle_air_bytes"],
            "signed": summaries["signed"]["mean_bundle_air_bytes"],
        },
        "wall_s": {k: round(v, 2) for k, v in wall.items()},
    }


def main(argv: list[str] | None = None) -> None:
    """Run the grid, print a table, write the summary."""
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--drops", default="0,0.5")
    p.add_argument("--runs", type=int, default=5)
    p.add_argument("--robots", type=int, default=6)
    p.add_argument("--seconds", type=float, default=120.0)
    p.add_argument("--out", type=Path, default=Path("docs/results/attack"))
    args = p.parse_args(argv)
    logging.disable(logging.WARNING)  # every forged bundle is logged by each receiver
    try:
        run_grid(args)
    finally:
        logging.disable(logging.NOTSET)


def run_grid(args: argparse.Namespace) -> None:
    """The runs `args` ask for: the table on stdout, the summary in args.out."""
    drops = [float(d) for d in args.drops.split(",")]
    plan = make_plan(
        "task-allocation",
        robots=[args.robots],
        drops=drops,
        runs=args.runs,
        seconds=args.seconds,
    )
    runs = []
    print("drop seed unchanged accepted(signed/none) plain-changed  air B (none/signed)  "
          "wall s (none/signed/attacked)")  # fmt: skip
    for spec in plan.specs():
        r = one_run(spec.config())
        runs.append(r)
        acc, air, wall = r["accepted_from_attacker"], r["mean_bundle_air_bytes"], r["wall_s"]
        assert isinstance(acc, dict) and isinstance(air, dict) and isinstance(wall, dict)
        print(
            f"{r['drop']:4} {r['seed']:4} {r['unchanged_by_attack']!s:9} "
            f"{acc['signed']}/{acc['none']:<16} {r['plain_swarm_changed_by_attack']!s:13} "
            f"{air['none']:.1f}/{air['signed']:.1f}        "
            f"{wall['none']:.1f}/{wall['signed']:.1f}/{wall['signed+attack']:.1f}"
        )
    total = {k: sum(float(r["wall_s"][k]) for r in runs) for k in runs[0]["wall_s"]}  # type: ignore[index]
    summary = {
        "experiment": "task-allocation",
        "robots": args.robots,
        "seconds": args.seconds,
        "drops": drops,
        "runs": runs,
        "all_unchanged": all(r["unchanged_by_attack"] for r in runs),
        "accepted_from_attacker_signed": sum(
            int(r["accepted_from_attacker"]["signed"])
            for r in runs  # type: ignore[index]
        ),
        "wall_ratio_signed_over_none": round(total["signed"] / total["none"], 3),
        "wall_ratio_attacked_over_signed": round(total["signed+attack"] / total["signed"], 3),
    }
    args.out.mkdir(parents=True, exist_ok=True)
    path = args.out / "summary.json"
    path.write_text(json.dumps(summary, indent=2) + "\n")
    print(
        f"unchanged by the attack in {sum(bool(r['unchanged_by_attack']) for r in runs)}/"
        f"{len(runs)} runs; accepted from the attacker (signed): "
        f"{summary['accepted_from_attacker_signed']}; wall signed/none "
        f"{summary['wall_ratio_signed_over_none']}, attacked/signed "
        f"{summary['wall_ratio_attacked_over_signed']}"
    )
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
