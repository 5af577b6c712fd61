"""What adaptation does per held-out family: an enrolment, ``adapt``, then the family's game
sessions with the shipped method and with the model (docs/method.md, "Adaptation").

    python3 benchmarks/adapt_eval.py --out DIR [--families powerlaw,drift,...] [--users 0,3]
        [--seed 2] [--enrol-seed 101] [--jobs 2] [--final-run]

Protocol (docs/method.md, "Adaptation"):

* **Test sessions**: ``family_eval.py --sessions``'s datasets (``family_eval.family_dataset``: one
  10 s game session per test user, even ``--seed``; the family's creep calibrated on a tuning
  user's press), written under ``DIR/FAMILY``.
* **Enrolment**, per family and test user (the same hand, "your hand"): the guided session's plan
  (``enrolment/plan.py``, ``make_plan(--enrol-seed + user)``, at most 3 minutes) performed by the
  simulated hand on the family's gel (``enrolment/hand.py``, seed ``--enrol-seed + user``: odd,
  never a test draw), labelled from the plan and the gel's motion as ``enrol --from`` does
  (``enrolment/label.py``: not the simulator's labels), with the family's calibrated creep.
* **Adapt**: ``neurotouch-hid adapt``'s code on that enrolment -> ``DIR/models/FAMILY/uUSER.yaml``.
* **Score**: each user's sessions through the pipeline with the shipped method and with the user's
  model applied (``enrolment.model.apply_model``: what ``track --model`` runs), the paper's metrics
  and the per-gesture ones (0.8 mm dead zone), pooled over the users.
* Adaptation's choices (prior strengths, hold-out, candidate values) were made on ``fingers`` and
  ``default`` only; every other family is held out for them. ``contrast`` (the final family) and
  ``mix`` need ``--final-run``, as in ``family_eval.py``.

Results are cached in ``DIR/results.json``; the table is printed and written to ``DIR/adapt.md``.
"""

from __future__ import annotations

import json
import sys
from concurrent.futures import ProcessPoolExecutor
from dataclasses import replace
from pathlib import Path

import typer

sys.path.insert(0, str(Path(__file__).resolve().parent))
from family_eval import HELD_BACK, family_dataset, parse_users  # noqa: E402  (the family protocol, reused)

from neurotouch_hid.views.console import command_app, make_console  # noqa: E402

#: Families adaptation's choices were looked at on (never reported as held out).
ADAPT_TUNING = ("default", "fingers")
#: The targets of an adapted gel (docs/dataset.md's per-gesture metrics): key, label, target, higher is better.
TARGETS = (
    ("gesture_accuracy", "gesture", 0.97, True),
    ("contact_count_accuracy", "count", 0.95, True),
    ("felt_wrong_share", "felt wrong", 0.05, False),
    ("deadzone_latency_p90_ms", "dead-zone p90 ms", 50.0, False),
    ("missed_above_deadzone", "missed above dead zone", 0, False),
    ("false_activations", "false activations", 0, False),
)

app = command_app()


def enrol(out: Path, fam: str, user: int, seed: int, creep) -> Path:
    """The labelled enrolment of ``user`` on ``fam``'s gel (module docstring), written once."""
    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.enrolment.hand import simulate_enrolment
    from neurotouch_hid.enrolment.label import label_recording
    from neurotouch_hid.enrolment.plan import make_plan

    raw, labelled = out / "raw", out / "labelled"
    if (labelled / "done").exists():
        return labelled
    plan = make_plan(seed)
    simulate_enrolment(plan, raw, seed=seed, user=user, physics=fam)
    sensor = replace(SensorGeometry.load(raw / "sensor.yaml"), creep=creep)
    sensor.save(raw / "sensor.yaml")
    label_recording(raw / "enrolment.aedat4", plan, labelled, sensor)
    (labelled / "done").write_text("")
    return labelled


def family(out: Path, fam: str, users: list[int], seed: int, enrol_seed: int, labels: str = "enrol") -> dict:
    """One family: enrol and adapt each user, score the sessions both ways (module docstring);
    ``labels`` ``simulator``: adapt on the simulator's own labels of the enrolment instead."""
    from neurotouch_hid.core.dataset import list_sequences
    from neurotouch_hid.core.sensor import SensorGeometry
    from neurotouch_hid.enrolment.adapt import adapt, fitted_info, summary
    from neurotouch_hid.enrolment.adapt_record import record_datasets
    from neurotouch_hid.enrolment.model import Model, apply_model
    from neurotouch_hid.evaluation.metrics import Observations, evaluate
    from neurotouch_hid.evaluation.runner import run_sequence

    folder = family_dataset(out, fam, sessions=True, seed=seed, users=users, creep=fam != "mix")
    creep = SensorGeometry.load(folder / "sensor.yaml").creep
    parts: dict[str, list] = {"shipped": [], "adapted": []}
    adapted = []
    for user in users:
        enrolment = enrol(out / "enrol" / fam / f"u{user}", fam, user, enrol_seed + user, creep)
        if labels == "simulator":
            enrolment = enrolment.parent / "raw"
        adaptation = adapt(record_datasets([enrolment]), rerun=lambda c, e=enrolment: record_datasets([e], config=c))
        model = Model(adaptation.model.settings, adaptation.model.classifier, fitted_info(adaptation, [enrolment]))
        model.save(out / "models" / labels / fam / f"u{user}.yaml")
        adapted.append({"user": user, "summary": summary(adaptation), "changes": model.changes()})
        config = apply_model(None, model)
        for name in list_sequences(folder):
            if name.startswith(f"u{user}_"):
                parts["shipped"].append(run_sequence(folder, name, None))
                parts["adapted"].append(run_sequence(folder, name, config))
    row = {"adapt": adapted}
    for method, obs in parts.items():
        result = evaluate(Observations.concatenate(obs)).to_dict()
        row[method] = {
            "gesture_accuracy": result["gesture_accuracy"],
            "contact_count_accuracy": result["contact_count_accuracy"],
            **result["felt"],
        }
    return row


def fmt(key: str, value, row: dict) -> str:
    if value is None:
        return "-"
    if key in ("gesture_accuracy", "contact_count_accuracy", "felt_wrong_share"):
        return f"{100 * value:.2f} %" if key != "felt_wrong_share" else f"{100 * value:.1f} % of {row['n_gestures']}"
    if key == "missed_above_deadzone":
        return f"{value} of {row['reached_deadzone']}"
    if key == "false_activations":
        return f"{value} of {row['n_rest']}"
    return f"{value:.0f}"


def report(cache: dict, families: list[str]) -> list[str]:
    """Markdown: per family, the shipped method and the adapted one (a * marks a missed target),
    then what each user's adapt changed and its held-out check."""
    lines = ["| family | method | " + " | ".join(t[1] for t in TARGETS) + " |"]
    lines.append("| --- | --- |" + " ---: |" * len(TARGETS))
    notes = []
    for fam in families:
        if fam not in cache:
            continue
        for method in ("shipped", "adapted"):
            row = cache[fam][method]
            cells = []
            for key, _, target, higher in TARGETS:
                value = row.get(key)
                ok = value is not None and (value >= target if higher else value <= target)
                cells.append(fmt(key, value, row) + ("" if ok else " *"))
            lines.append(f"| {fam} | {method} | " + " | ".join(cells) + " |")
        for a in cache[fam]["adapt"]:
            notes.append(f"- {fam}, user {a['user']}: " + "; ".join(a["summary"][1:]))
    return lines + [""] + notes


@app.command()
def main(
    out: Path = typer.Option(..., "--out", help="working folder: datasets, enrolments, models, results.json"),
    families: str = typer.Option(
        "powerlaw,drift,strong,viscoelastic,late,camera",
        "--families",
        help=f"comma-separated held-out families; {', '.join(HELD_BACK)} and mix need --final-run",
    ),
    users: str = typer.Option("0,3", "--users", help="test users (0-4)"),
    seed: int = typer.Option(2, "--seed", help="even: the test sessions' seed"),
    enrol_seed: int = typer.Option(101, "--enrol-seed", help="odd: the enrolments' seed (plus the user id)"),
    jobs: int = typer.Option(2, "--jobs", min=1, help="families run in parallel processes"),
    final_run: bool = typer.Option(False, "--final-run", help=f"permit {', '.join(HELD_BACK)} and mix"),
    rerun: bool = typer.Option(False, "--rerun", help="recompute cached families"),
    labels: str = typer.Option(
        "enrol",
        "--labels",
        help="enrol: the enrolment labelled as enrol --from does; simulator: the simulator's own labels of it "
        "(what adapt could do with perfect labels)",
    ),
) -> None:
    import multiprocessing

    console = make_console()
    names = [f.strip() for f in families.split(",") if f.strip()]
    if {*HELD_BACK, "mix"} & set(names) and not final_run:
        raise typer.BadParameter(f"kept untouched until the final run: {', '.join(HELD_BACK)} and mix; add --final-run")
    if set(ADAPT_TUNING) & set(names):
        console.print(f"note: {', '.join(ADAPT_TUNING)} were looked at for adaptation's choices: not held out")
    user_ids = parse_users(users)
    out.mkdir(parents=True, exist_ok=True)
    if labels not in ("enrol", "simulator"):
        raise typer.BadParameter(f"--labels {labels}: expected enrol or simulator")
    suffix = "" if labels == "enrol" else "-simulator"
    cache_path = out / f"results{suffix}.json"
    cache = json.loads(cache_path.read_text()) if cache_path.exists() else {}
    todo = [f for f in names if rerun or f not in cache]
    ctx = multiprocessing.get_context("spawn")
    with ProcessPoolExecutor(max_workers=jobs, mp_context=ctx) as pool:
        futures = {f: pool.submit(family, out, f, user_ids, seed, enrol_seed, labels) for f in todo}
        for fam, future in futures.items():
            cache[fam] = future.result()
            cache_path.write_text(json.dumps(cache, indent=1) + "\n")
            console.print(f"{fam}: done", highlight=False)
    lines = report(cache, names)
    (out / f"adapt{suffix}.md").write_text("\n".join(lines) + "\n")
    console.print("\n".join(lines), highlight=False, soft_wrap=True)
    console.print(f"-> {out / f'adapt{suffix}.md'}")


if __name__ == "__main__":
    app()
