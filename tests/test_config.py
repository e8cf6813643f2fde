from pathlib import Path

import pytest

from activetouch.config import load_config
from activetouch.errors import ConfigError


def test_defaults_are_the_papers_where_not_measured_otherwise():
    cfg = load_config()
    assert cfg.planner.exploration_c == 1.0
    assert cfg.planner.horizon == 5
    # Measured in the twin (docs/planner.md): these differ from the paper's 0.5 / final.
    assert cfg.planner.lam == 0.0
    assert cfg.planner.objective == "anytime"
    assert cfg.observation.translation_cell_m == 0.06
    assert cfg.recognition.bins == 10


def test_toml_and_overrides(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text('[planner]\nhorizon = 7\npolicy = "greedy"\n')
    cfg = load_config(f, ["planner.simulations=50", "grid.rolls_deg=[0.0]"])
    assert cfg.planner.horizon == 7
    assert cfg.planner.policy == "greedy"
    assert cfg.planner.simulations == 50
    assert cfg.grid.rolls_deg == [0.0]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("[planner]\nhorizon = 'x'\n", "planner.horizon: expected an integer"),
        ("[planner]\nhorizn = 3\n", "unknown setting 'planner.horizn'"),
        ("[planner\n", "not valid TOML"),
        ("planner = 3\n", "planner: expected a table"),
    ],
)
def test_bad_files_name_the_problem(tmp_path, text, message):
    f = tmp_path / "c.toml"
    f.write_text(text)
    with pytest.raises(ConfigError, match=message):
        load_config(f)


def test_missing_file_and_bad_override(tmp_path):
    with pytest.raises(ConfigError, match="no such config file"):
        load_config(tmp_path / "nope.toml")
    with pytest.raises(ConfigError, match=r"expected section\.key=value"):
        load_config(None, ["planner.horizon"])


def test_words_outside_their_choices_are_refused():
    with pytest.raises(ConfigError, match=r"recognition\.classifier: 'bogus' is not one of"):
        load_config(None, ["recognition.classifier=bogus"])
    with pytest.raises(ConfigError, match=r"observation\.granularity"):
        load_config(None, ["observation.granularity=pixels"])


def test_file_errors_name_the_file(tmp_path):
    f = tmp_path / "c.toml"
    f.write_text("[planner]\nhorizon = 'x'\n")
    with pytest.raises(ConfigError, match=r"c\.toml: planner\.horizon: expected an integer"):
        load_config(f)
    with pytest.raises(ConfigError, match="cannot read the config file"):
        load_config(tmp_path)  # a directory


def test_an_arm_that_cannot_use_the_default_workcell_gets_its_own() -> None:
    # The default table stands at the base frame's origin, inside Baxter: `--set
    # arm.type=twin-baxter` alone takes Baxter's (deploy/baxter-twin.toml's) instead.
    from activetouch.config import WorkcellConfig

    floating = load_config(None, [])
    assert floating.workcell == WorkcellConfig()
    baxter = load_config(None, ["arm.type=twin-baxter"])
    assert baxter.workcell.table_center == [0.85, 0.2, -0.205]
    assert baxter.workcell.object_xyz[:2] == [0.6, 0.25]
    assert baxter.workcell.table_top_z == pytest.approx(-0.18)
    toml = load_config(Path(__file__).parents[1] / "deploy" / "baxter-twin.toml", [])
    assert toml.workcell == baxter.workcell
    # A workcell the user set is kept, even one that will be refused later.
    mine = load_config(None, ["arm.type=twin-baxter", "workcell.object_xyz=[0.7, 0.1, -0.1]"])
    assert mine.workcell.object_xyz == [0.7, 0.1, -0.1]
    assert mine.workcell.table_center == WorkcellConfig().table_center


def test_profiles_start_the_settings_and_the_file_and_overrides_still_win(tmp_path):
    from activetouch.config import PROFILES, profile_line

    assert load_config().profile == "robust"
    paper = load_config(None, ["profile=paper"])
    assert paper.profile == "paper"
    for dotted, value in PROFILES["paper"].items():
        section, key = dotted.split(".")
        assert getattr(getattr(paper, section), key) == value
    f = tmp_path / "c.toml"
    f.write_text('profile = "paper"\n[recognition]\nbelief = "pose"\n')
    cfg = load_config(f)
    assert cfg.profile == "paper" and cfg.recognition.belief == "pose"  # the file wins
    assert load_config(f, ["profile=robust"]).profile == "robust"  # the override wins
    assert profile_line(paper).startswith("paper: recognition.belief histogram")
    # A recognition asked for another policy names that one, not the configured one.
    assert "planner.policy tree," in profile_line(paper)
    assert "planner.policy greedy," in profile_line(paper, "greedy")
    with pytest.raises(ConfigError, match="profile: 'fast' is not one of robust, paper"):
        load_config(None, ["profile=fast"])


def test_the_profile_flag_reaches_the_configuration(tmp_path, capsys):
    from activetouch.cli.main import main

    rc = main(["recognize", "--profile", "paper", "--object", "mug", "--data", str(tmp_path)])
    out = capsys.readouterr()
    assert rc != 0 and "no model" in out.err  # a clear error, after saying what it would use
    assert "profile paper: recognition.belief histogram" in out.out
    main(["recognize", "--object", "mug", "--data", str(tmp_path)])
    assert "profile robust:" in capsys.readouterr().out
