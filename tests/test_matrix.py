import pickle

import pytest

from campaign.errors import UserError
from campaign.simulation.matrix import StatusPoint, load_matrix


def test_default_matrix_is_the_papers_fig3(matrix):
    up = [p for p in matrix.points if not p.gear_down]
    down = [p for p in matrix.points if p.gear_down]
    assert (len(up), len(down)) == (56, 41)
    by_flap = {f: sum(1 for p in down if p.flap_deg == f) for f in (0, 1, 5, 15, 30)}
    assert by_flap == {0: 15, 1: 7, 5: 7, 15: 6, 30: 6}
    assert all(p.maneuvers == ("doublet", "gear_extension") for p in down)
    assert all(p.maneuvers == ("doublet",) for p in up)


def test_point_ids_are_stable_readable_and_pickle():
    p = StatusPoint(2000.0, 0.3, 5, True, None, ("doublet",))
    assert p.id == "h02000_m0.30_f05_gdn"
    q = pickle.loads(pickle.dumps(p))
    assert q == p and q.id == p.id
    with pytest.raises(AttributeError):
        p.mach = 0.4


@pytest.mark.parametrize(
    "text, field",
    [
        ('name = "x"\nbogus = 1\n[[points]]\ngear="up"\nflap_deg=0\nmach=0.3\nalt_ft=2000\n', "bogus"),
        ('[[points]]\ngear="up"\nflap_deg=0\nmach=0.3\nalt_ft=2000\nmachh=1\n', "points[0].machh"),
        ('[[points]]\ngear="up"\nflap_deg=0\nmach=0.0\nalt_ft=2000\n', "points[0].mach"),
        ('[[points]]\ngear="up"\nflap_deg=0\nmach=-0.2\nalt_ft=2000\n', "points[0].mach"),
        ('[[points]]\ngear="up"\nflap_deg="5"\nmach=0.3\nalt_ft=2000\n', "points[0].flap_deg"),
        ('[[points]\ngear="up"\n', "TOML does not parse"),
        ('[[points]]\ngear="sideways"\nflap_deg=0\nmach=0.3\nalt_ft=2000\n', "points[0].gear"),
        (
            '[maneuvers.doublet]\namplitude=3\n[[points]]\ngear="up"\nflap_deg=0\nmach=0.3\nalt_ft=2000\n',
            "maneuvers.doublet.amplitude",
        ),
    ],
)
def test_bad_matrix_names_file_and_field(tmp_path, text, field):
    p = tmp_path / "bad.toml"
    p.write_text(text)
    with pytest.raises(UserError) as err:
        load_matrix(p)
    msg = str(err.value)
    assert str(p) in msg and field in msg and "\n" not in msg


def test_a_left_turn_is_a_negative_bank_and_its_size_is_still_checked(tmp_path):
    head = 'name = "t"\n[[points]]\ngear = "up"\nflap_deg = 0\nmach = 0.3\nalt_ft = 10000\nmaneuvers = ["level_turn"]\n'
    f = tmp_path / "m.toml"
    f.write_text(head + "[maneuvers.level_turn]\nbank_deg = -20.0\n")
    assert load_matrix(f).params_for("level_turn") == {"bank_deg": -20.0}  # the time at full bank from the trim
    for bad, said in (
        ("bank_deg = -40.0", "bank_deg must be within"),
        ("bank_deg = 0", "bank_deg must be within"),
        ("turn_s = -5", "turn_s: must be > 0"),
        ("turn_s = 0", "turn_s: must be > 0"),
    ):
        f.write_text(head + f"[maneuvers.level_turn]\n{bad}\n")
        with pytest.raises(UserError, match=said):
            load_matrix(f)
