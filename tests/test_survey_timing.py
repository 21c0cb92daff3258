"""The survey benchmark (`experiments/survey_timing.py`): every phase from a survey folder to the °C map, each in
a fresh process through the command a user runs, its seconds and peak memory written; on a CPU, a real drone
survey at 1/8 of its resolution for a few steps (no timing asserted)."""

import json

import pytest
from real_data import FLIGHT2


@pytest.mark.slow  # trains and scores through nerfstudio's commands: minutes on a CPU
@pytest.mark.skipif(not FLIGHT2.is_dir(), reason=f"{FLIGHT2} is not here")
def test_every_phase_from_the_folder_to_the_orthomosaic_is_timed(tmp_path):
    from experiments.survey_timing import PHASES, SurveyTimingArgs, main

    folder = tmp_path / "flight2"
    folder.symlink_to(FLIGHT2, target_is_directory=True)
    args = SurveyTimingArgs(
        surveys=[f"metashape:{folder}"],
        output_dir=tmp_path / "out",
        max_steps=4,
        train_options="--pipeline.datamanager.camera-res-scale-factor 0.125 --pipeline.eval-fit-steps 0",
        orthomosaic_options="--ground-resolution 1.0 --min-coverage 0",  # a 4-step model covers little
    )
    (row,) = main(args)
    assert list(row["phases"]) == list(PHASES)
    for phase, record in row["phases"].items():
        assert "failed" not in record, (phase, record.get("failed"))
        assert record["seconds"] > 0 and record["peak_host_mb"] > 100, (phase, record)
    out = tmp_path / "out"
    assert json.loads((out / "survey_timing.json").read_text()) == [row]
    assert (out / "survey_timing.png").stat().st_size > 0
    table = (out / "survey_timing.md").read_text()
    assert table.count("\n") == 3 and "failed" not in table and "skipped" not in table
    ortho = next(out.glob("*/ortho.tif"))  # the phases' own outputs: the map and the points
    assert ortho.stat().st_size > 0 and next(out.glob("*/points.ply")).stat().st_size > 0


def test_runs_of_separate_calls_are_tabled_together_and_a_cut_row_says_so(tmp_path):
    """Each survey may be timed in its own device call; `--merge` tables their rows, and a row whose phases did not
    all finish gives no total as if it were whole."""
    from experiments.survey_timing import PHASES, SurveyTimingArgs, main

    record = {"seconds": 2.0, "peak_host_mb": 900.0, "peak_child_host_mb": 0.0, "peak_gpu_mb": 10.0}
    whole = {"survey": "survey:250", "phases": {p: dict(record) for p in PHASES}}
    cut = {"survey": "survey:1000", "phases": {"setup": dict(record), "train": {"failed": "killed"}}}
    files = []
    for i, row in enumerate((whole, cut)):
        files.append(tmp_path / f"call{i}.json")
        files[-1].write_text(json.dumps([row]))
    rows = main(SurveyTimingArgs(surveys=[], merge=files, output_dir=tmp_path / "out"))
    assert rows == [whole, cut]
    table = (tmp_path / "out" / "survey_timing.md").read_text().splitlines()
    assert len(table) == 4
    assert table[2].endswith(f"| {2.0 * len(PHASES):.1f} |")
    assert "failed" in table[3] and table[3].endswith("| 2.0 so far (incomplete) |")
    assert json.loads((tmp_path / "out" / "survey_timing.json").read_text()) == rows


def test_the_phases_asked_alone_are_timed_and_the_row_says_it_is_incomplete(tmp_path):
    """`--phases setup` times the setup alone (a fresh process reading the generated survey); the other phases
    have no record, and the table gives no total as if the row were whole."""
    from experiments.survey_timing import SurveyTimingArgs, main

    (row,) = main(SurveyTimingArgs(surveys=["survey:12"], phases=["setup"], output_dir=tmp_path / "out"))
    assert list(row["phases"]) == ["setup"] and row["generate_seconds"] > 0
    assert "failed" not in row["phases"]["setup"] and row["phases"]["setup"]["seconds"] > 0
    line = (tmp_path / "out" / "survey_timing.md").read_text().splitlines()[2]
    assert line.endswith("so far (incomplete) |") and line.count("—") == 4
    frames = sorted((tmp_path / "out" / "survey-12" / "survey-12").rglob("*.png"))
    assert frames
    written = [frame.stat().st_mtime_ns for frame in frames]
    # a later run of the phases after setup reads the survey that run wrote: it is not generated again
    (row,) = main(SurveyTimingArgs(surveys=["survey:12"], phases=["orthomosaic"], output_dir=tmp_path / "out"))
    assert "generate_seconds" not in row and [frame.stat().st_mtime_ns for frame in frames] == written
    with pytest.raises(ValueError, match="--phases"):
        main(SurveyTimingArgs(surveys=["survey:12"], phases=["render"], output_dir=tmp_path / "bad"))


def test_a_surveys_phases_timed_in_separate_runs_join_into_its_one_row(tmp_path):
    """A large survey's phases may not fit one device call: timed in two (`--phases`), merged, they make one row in
    the phases' order, its total whole once every phase is there."""
    from experiments.survey_timing import PHASES, SurveyTimingArgs, main

    record = {"seconds": 3.0, "peak_host_mb": 900.0, "peak_child_host_mb": 0.0, "peak_gpu_mb": 10.0}
    first = {"survey": "survey:4000", "phases": {"setup": dict(record), "train": dict(record)}, "generate_seconds": 40}
    second = {"survey": "survey:4000", "phases": {p: dict(record) for p in PHASES[2:]}, "generate_seconds": 0.1}
    files = [tmp_path / "first.json", tmp_path / "second.json"]
    for path, row in zip(files, (first, second)):
        path.write_text(json.dumps([row]))
    (row,) = main(SurveyTimingArgs(surveys=[], merge=files, output_dir=tmp_path / "out"))
    assert list(row["phases"]) == list(PHASES) and row["generate_seconds"] == 40
    line = (tmp_path / "out" / "survey_timing.md").read_text().splitlines()[2]
    assert line.endswith(f"| {3.0 * len(PHASES):.1f} |")
