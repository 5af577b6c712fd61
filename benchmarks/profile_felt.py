"""What a gesture does through a profile, per family: wrong outputs, missed gestures, outputs at rest.

    python3 benchmarks/profile_felt.py --out DIR --method NAME [--families default,late,...]
        [--profiles default,switch-access,...]

DIR is a ``family_eval.py`` working folder (each family's dataset under ``DIR/FAMILY``, a
method's predictions under ``DIR/predictions/FAMILY/NAME``), typically made with ``--sessions``.
Each sequence's predictions are replayed through each shipped profile (or profile file) as
``neurotouch-hid eval --profile`` replays them (``neurotouch_hid/evaluation/through_profile.py``;
docs/dataset.md, "Through a profile"), without running the pipeline again: a Markdown table per
profile and family of the gestures with a wrong output, the gestures missed (of those whose
labels move an output of their type) and the rest windows in which an output went active.
"""

from __future__ import annotations

from pathlib import Path

import typer
from workdir import families_in, usage_error

from neurotouch_hid.core.dataset import list_sequences, read_labels, read_predictions
from neurotouch_hid.core.errors import DatasetError, ProfileError
from neurotouch_hid.core.sensor import SensorGeometry
from neurotouch_hid.evaluation.through_profile import ProfileTally, ProfileUnderTest, tally
from neurotouch_hid.mapping.profile import Profile, load_profile, shipped_profiles_dir
from neurotouch_hid.views.console import command_app

app = command_app()


@app.command()
def main(
    out: Path = typer.Option(..., "--out", help="family_eval.py working folder"),
    method: str = typer.Option(..., "--method", help="the method whose predictions to replay"),
    families: str = typer.Option("", "--families", help="comma-separated (default: every family of --out)"),
    profiles: str = typer.Option(
        "", "--profiles", help="comma-separated shipped profile names or profile files (default: every shipped one)"
    ),
) -> None:
    names = [p.strip() for p in profiles.split(",") if p.strip()] or sorted(
        p.stem for p in shipped_profiles_dir().glob("*.yaml")
    )
    tested = [ProfileUnderTest.probe(name, _shipped_or_path(name)) for name in names]
    chosen = families_in(out, families, method)
    geometry = {family: SensorGeometry.load(out / family / "sensor.yaml") for family in chosen}
    print("| profile | family | gestures | wrong output | missed (of those the labels move) | went active at rest |")
    print("| --- | --- | ---: | ---: | ---: | ---: |")
    for profile in tested:
        total = ProfileTally()
        for family in chosen:
            t = ProfileTally()
            for seq in list_sequences(out / family):
                try:
                    labels = read_labels(out / family / f"{seq}.labels.csv")
                    predictions = read_predictions(out / "predictions" / family / method / f"{seq}.jsonl")
                except DatasetError as exc:
                    usage_error(str(exc))
                t += tally(profile, labels, predictions, geometry[family])
            total += t
            print(_row(profile.name, family, t))
        print(_row(profile.name, f"**all {len(chosen)}**", total))


def _shipped_or_path(name: str) -> Profile:
    """A shipped profile by name (never the user's copy of it: the figures are the shipped
    file's), else a profile file's path; a usage error when neither loads."""
    shipped = shipped_profiles_dir() / f"{name}.yaml"
    try:
        return load_profile(shipped if shipped.is_file() else name)
    except ProfileError as exc:
        usage_error(str(exc))


def _row(profile: str, family: str, t: ProfileTally) -> str:
    return (
        f"| {profile} | {family} | {t.gestures} | {t.wrong} | {t.missed} of {t.ideal} | {t.rest_active} of {t.rest} |"
    )


if __name__ == "__main__":
    app()
