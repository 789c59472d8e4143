"""Lip-sync files -> step-hold tracks: review R1.2's numbers from every form, the forms alike
within one source frame (issue 13), the two vocabularies, the rig's table, bad inputs."""

from __future__ import annotations

import importlib.util
import math
from pathlib import Path

import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

from hilsim.targets.formats.common import FormatError, UnitMap
from hilsim.targets.formats.lipsync import (
    Cue,
    Cues,
    ShapeTable,
    cue_track,
    read_cues,
    read_moho_dat,
    read_papagayo,
    read_rhubarb_json,
    read_rhubarb_tsv,
    read_rhubarb_xml,
)

ROOT = Path(__file__).resolve().parents[2]
_spec = importlib.util.spec_from_file_location(
    "samples_lipsync", ROOT / "tools" / "samples_lipsync.py"
)
gen = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(gen)

JAW = UnitMap((0, 1), (0, 20), "opening")
TABLE = ShapeTable(rhubarb=dict(X=0, A=0, B=0.2, C=0.5, D=1.0, E=0.6, F=0.3, G=0.1, H=0.4))

#: form -> (file name, text, reader keywords, the source frame in s)
FORMS = {
    "tsv": ("hi.tsv", gen.rhubarb_tsv(), {}, 0.01),
    "json": ("hi.json", gen.rhubarb_json(), {}, 0.01),
    "xml": ("hi.xml", gen.rhubarb_xml(), {}, 0.01),
    "dat": ("hi.dat", gen.moho_dat(fps=100), {"fps": 100}, 0.01),
    "dat_blair_24": ("hi.dat", gen.moho_dat(fps=24, blair=True), {"fps": 24}, 1 / 24),
    "dat_30": ("hi.dat", gen.moho_dat(fps=30), {"fps": 30}, 1 / 30),
    "pgo_24": ("hi.pgo", gen.papagayo_pgo(fps=24), {}, 1 / 24),
    "pgo_100": ("hi.pgo", gen.papagayo_pgo(fps=100), {}, 0.01),
}


def write(tmp_path: Path, name: str, text: str | bytes) -> Path:
    path = tmp_path / name
    if isinstance(text, bytes):
        path.write_bytes(text)
    else:
        path.write_text(text, encoding="utf-8")
    return path


def track_of(tmp_path: Path, form: str, table: ShapeTable = TABLE):
    name, text, kw, _ = FORMS[form]
    return cue_track(read_cues(write(tmp_path, name, text), **kw), table, JAW)


def deg(track, t: float) -> float:
    return math.degrees(track.sample(t)[0])


@pytest.mark.parametrize("form", sorted(FORMS))
def test_review_r12_numbers_from_every_form(tmp_path, form):
    """README "Hi", jaw 0-20°: 0° at 0.02 s, 20° at 0.10, 10° at 0.29, 4° at 0.35, 0° at 0.45."""
    track = track_of(tmp_path, form)
    got = [deg(track, t) for t in (0.02, 0.10, 0.29, 0.35, 0.45)]
    assert got == pytest.approx([0.0, 20.0, 10.0, 4.0, 0.0], abs=1e-9)
    assert track.sample(0.2)[1] == 0.0  # step-hold: no velocity


@pytest.mark.parametrize("form", sorted(set(FORMS) - {"tsv"}))
def test_every_form_gives_the_tsv_track_within_one_source_frame(tmp_path, form):
    """Issue 13: at every time the form's jaw is the TSV's jaw at a time at most one of the
    form's frames away (Rhubarb's own forms: exactly the TSV's)."""
    tsv = track_of(tmp_path, "tsv")
    other = track_of(tmp_path, form)
    frame = FORMS[form][3]
    times = np.arange(0.0, 0.6, 0.0005)
    mine = other.sample_array(times)[0]
    if form in ("json", "xml"):
        assert np.array_equal(mine, tsv.sample_array(times)[0]) and other.duration == tsv.duration
        return
    shifts = np.linspace(-frame, frame, 41)
    near = np.stack([tsv.sample_array(times + s)[0] for s in shifts])
    assert np.all(np.any(np.isclose(near, mine, atol=1e-12), axis=0))


def test_cue_positions_are_kept_for_messages(tmp_path):
    cues = read_cues(write(tmp_path, "hi.xml", gen.rhubarb_xml()))
    assert [c.where for c in cues.cues] == ["line 8", "line 9", "line 10", "line 11", "line 12"]
    assert cues.end_s == pytest.approx(0.47) and cues.vocabulary == "rhubarb"
    pgo = read_cues(write(tmp_path, "hi.pgo", gen.papagayo_pgo(fps=24)))
    assert [(round(c.time_s * 24), c.shape) for c in pgo.cues] == [
        (0, "rest"), (1, "AI"), (6, "E"), (7, "etc"), (10, "rest")]  # fmt: skip
    assert pgo.vocabulary == "preston_blair" and pgo.end_s == 0.5


# ---------------------------------------------------------------------------- vocabularies


def test_e_means_rhubarb_e_or_blair_e_as_the_file_says(tmp_path):
    only_e = write(tmp_path, "e.dat", "MohoSwitch1\n1 E\n5 E\n")
    with pytest.raises(FormatError, match="say names = rhubarb or preston_blair"):
        read_moho_dat(only_e, 24)
    as_rhubarb = cue_track(read_moho_dat(only_e, 24, names="rhubarb"), TABLE, JAW)
    as_blair = cue_track(read_moho_dat(only_e, 24, names="preston_blair"), TABLE, JAW)
    assert deg(as_rhubarb, 0.1) == pytest.approx(12.0)  # Rhubarb E = 0.6
    assert deg(as_blair, 0.1) == pytest.approx(10.0)  # Blair E = Rhubarb C = 0.5
    letters = write(tmp_path, "l.dat", "MohoSwitch1\n1 X\n3 E\n")
    blair = write(tmp_path, "b.dat", "MohoSwitch1\n1 rest\n3 E\n")
    assert read_moho_dat(letters, 24).vocabulary == "rhubarb"
    assert read_moho_dat(blair, 24).vocabulary == "preston_blair"
    mixed = write(tmp_path, "m.dat", "MohoSwitch1\n1 X\n3 AI\n")
    with pytest.raises(FormatError, match=r"mixes Rhubarb shapes \(line 2: 'X'\) and Preston"):
        read_moho_dat(mixed, 24)


def test_wq_needs_the_rig_and_the_blair_table_can_be_numbers_or_letters(tmp_path):
    text = gen.papagayo_pgo(fps=24).replace("6 E", "6 WQ")
    path = write(tmp_path, "wq.pgo", text)
    with pytest.raises(FormatError, match=r"wq.pgo:line 15: phoneme 'WQ' is not in the rig's"):
        cue_track(read_papagayo(path), TABLE, JAW)
    as_letter = ShapeTable(rhubarb=TABLE.rhubarb, preston_blair={"WQ": "F"})
    assert deg(cue_track(read_papagayo(path), as_letter, JAW), 0.29) == pytest.approx(6.0)
    as_number = ShapeTable(rhubarb=TABLE.rhubarb, preston_blair={"WQ": 0.25, "AI": 0.9})
    track = cue_track(read_papagayo(path), as_number, JAW)
    assert deg(track, 0.29) == pytest.approx(5.0) and deg(track, 0.1) == pytest.approx(18.0)
    blair_only = ShapeTable(preston_blair={"AI": 1, "E": 0.5, "etc": 0.2, "rest": 0, "WQ": 0.3})
    assert deg(cue_track(read_papagayo(path), blair_only, JAW), 0.1) == 20.0
    no_x = ShapeTable(rhubarb={"D": 1.0})
    with pytest.raises(FormatError, match=r"line 14: phoneme 'AI'|rest.*'X'"):
        cue_track(read_papagayo(path), no_x, JAW)


def test_unknown_rhubarb_shape_names_its_line(tmp_path):
    path = write(tmp_path, "y.tsv", "0.00\tX\n0.10\tY\n0.20\tX\n")
    with pytest.raises(FormatError, match=r"y.tsv:line 2: Rhubarb shape 'Y' is not in the rig"):
        cue_track(read_rhubarb_tsv(path), TABLE, JAW)


def test_cues_at_one_time_the_last_counts():
    cues = Cues("c", (Cue(0.0, "X", "1"), Cue(0.1, "A", "2"), Cue(0.1, "D", "3")), "rhubarb")
    assert deg(cue_track(cues, TABLE, JAW), 0.1) == 20.0


@pytest.mark.parametrize(
    ("kw", "match"),
    [({"rhubarb": {"Y": 1}}, "not a Rhubarb shape"), ({"rhubarb": {"A": math.nan}}, "finite"),
     ({"rhubarb": {"A": True}}, "finite"), ({"preston_blair": {"WQ": "Q"}}, "Rhubarb shape"),
     ({"preston_blair": {"two words": 1}}, "phoneme name")],
)  # fmt: skip
def test_bad_tables_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        ShapeTable(**kw)


def test_papagayo_voices(tmp_path):
    one = gen.papagayo_pgo(fps=24).splitlines()
    head, voice = one[:4], one[5:]
    second = [line.replace("Voice 1", "Bob") for line in voice]
    path = write(tmp_path, "two.pgo", "\n".join([*head, "2", *voice, *second]) + "\n")
    with pytest.raises(FormatError, match=r"2 voices \(Voice 1, Bob\): say which"):
        read_papagayo(path)
    bob, first = read_papagayo(path, "Bob").cues, read_papagayo(path, 0).cues
    assert [(c.time_s, c.shape) for c in bob] == [(c.time_s, c.shape) for c in first]
    assert bob[1].where == "line 25" and first[1].where == "line 14"
    with pytest.raises(FormatError, match="no voice 'Alice'"):
        read_papagayo(path, "Alice")


def test_papagayo_rests_between_words(tmp_path):
    text = "\n".join(["lipsync version 1", "a.wav", "10", "20", "1", "\tV", "\tab", "\t1", "\tab",
                      "\t2", "\t9", "\t2", "\t\ta 2 3 1", "\t\t\t2 AI", "\t\tb 6 8 1",
                      "\t\t\t6 O"]) + "\n"  # fmt: skip
    cues = read_papagayo(write(tmp_path, "w.pgo", text))
    assert [(round(c.time_s * 10), c.shape) for c in cues.cues] == [
        (0, "rest"), (2, "AI"), (4, "rest"), (6, "O"), (9, "rest")]  # fmt: skip
    assert cues.end_s == 2.0


def test_read_cues_dispatch(tmp_path):
    with pytest.raises(ValueError, match="holds no frame rate"):
        read_cues(write(tmp_path, "a.dat", gen.moho_dat()))
    with pytest.raises(ValueError, match="lip-sync kind None"):
        read_cues(write(tmp_path, "a.csv", "x"))
    assert read_cues(write(tmp_path, "a.txt", gen.rhubarb_tsv())).cues[1].shape == "D"
    with pytest.raises(ValueError, match="fps"):
        read_moho_dat(write(tmp_path, "b.dat", gen.moho_dat()), 0)


# ---------------------------------------------------------------------------- bad inputs

TSV, JSON, XML = "t.tsv", "j.json", "x.xml"
DAT, PGO = "d.dat", "p.pgo"
PGO_OK = gen.papagayo_pgo(fps=24)
BAD = {
    "empty": (TSV, "", r"t.tsv: empty file"),
    "blank": (JSON, " \n\n", r"empty file"),
    "binary": (TSV, b"0.00\tX\n\0\x01", r"t.tsv:byte 7: a NUL byte"),
    "latin-1": (XML, b"<r>\xe9</r>", r"byte 3: not UTF-8"),
    "tsv time": (TSV, "0.00\tX\nabc\tD\n", r"line 2: time must be a number of seconds, got 'abc'"),
    "tsv nan": (TSV, "nan\tX\n", r"line 1: time 'nan': allowed 0 .. 1e7 s"),
    "tsv negative": (TSV, "-1\tX\n", r"line 1: time '-1'"),
    "tsv order": (TSV, "0.00\tX\n0.30\tD\n0.20\tC\n", r"line 3: time 0.2 s comes before"),
    "tsv fields": (TSV, "0.00\tX\textra\n", r"line 1: expected 'time<TAB>shape'"),
    "json syntax": (JSON, '{"mouthCues": [\n{"start": 0,}\n]}', r"j.json:line 2: not JSON"),
    "json deep": (JSON, "[" * 100_000 + "]" * 100_000, r"j.json: not usable JSON"),
    "json shape": (JSON, '{"cues": []}', r'no "mouthCues" list'),
    "json cue": (JSON, '{"mouthCues": [{"start": 0, "value": "X"}]}', r"mouthCues\[0\]: a cue"),
    "json bool": (JSON, '{"mouthCues": [{"start": true, "end": 1, "value": "X"}]}',
                  r"mouthCues\[0\]: start must be a number"),
    "json inf": (JSON, '{"mouthCues": [{"start": 0, "end": 1e999, "value": "X"}]}',
                 r"mouthCues\[0\]: end 'inf'"),
    "json gap": (JSON, '{"mouthCues": [{"start": 0, "end": 0.1, "value": "X"},'
                 '{"start": 0.2, "end": 0.3, "value": "D"}]}',
                 r"mouthCues\[1\]: starts at 0.2 s, the cue before ends at 0.1 s"),
    "json backwards": (JSON, '{"mouthCues": [{"start": 0.5, "end": 0.1, "value": "X"}]}',
                       r"end 0.1 s is before start 0.5 s"),
    "json value": (JSON, '{"mouthCues": [{"start": 0, "end": 1, "value": "A B"}]}',
                   r"mouth shape must be one word"),
    "xml dtd": (XML, '<?xml version="1.0"?>\n<!DOCTYPE r [<!ENTITY a "aaaa">]>\n<r>&a;</r>',
                r"x.xml:line 2: a DTD"),
    "xml root": (XML, "<svg/>", r"line 1: not Rhubarb XML: root <svg>"),
    "xml syntax": (XML, "<rhubarbResult>\n<mouthCues>\n</rhubarbResult>",
                   r"line 3: not XML: mismatched tag"),
    "xml attr": (XML, '<rhubarbResult>\n<mouthCue start="0">X</mouthCue></rhubarbResult>',
                 r'line 2: <mouthCue> needs start="s" and end="s"'),
    "xml none": (XML, "<rhubarbResult/>", r"no <mouthCue> elements"),
    "xml nested": (XML, '<rhubarbResult><mouthCue start="0" end="1"><b/></mouthCue>'
                   "</rhubarbResult>", r"<b> inside a <mouthCue>"),
    "dat magic": (DAT, "MohoSwitch2\n1 X\n", r"d.dat:line 1: not a Moho switch file"),
    "dat frame 0": (DAT, "MohoSwitch1\n0 X\n", r"line 2: frame 0: allowed 1 or more"),
    "dat frame text": (DAT, "MohoSwitch1\n1.5 X\n", r"line 2: frame must be a whole number"),
    "dat huge frame": (DAT, "MohoSwitch1\n" + "9" * 5000 + " X\n", r"line 2: frame must be"),
    "dat shape": (DAT, "MohoSwitch1\n1\n", r"line 2: expected '<frame> <shape>'"),
    "dat empty": (DAT, "MohoSwitch1\n\n", r"no cues after 'MohoSwitch1'"),
    "dat order": (DAT, "MohoSwitch1\n5 X\n2 D\n", r"line 3: time 0.0416667 s comes before the cue above \(0.166667 s at line 2\)"),
    "pgo magic": (PGO, "lipsync version 2\n", r"p.pgo:line 1: not a Papagayo file"),
    "pgo fps": (PGO, PGO_OK.replace("\n24\n", "\n24.5\n", 1), r"line 3: frame rate must be"),
    "pgo fps 0": (PGO, PGO_OK.replace("\n24\n", "\n0\n", 1), r"line 3: frame rate 0: allowed 1"),
    "pgo huge counts": (PGO, "lipsync version 1\na.wav\n24\n10\n999999999\n\tV\n\tt\n",
                        r"line 8: the file ends where a number of phrases should be"),
    "pgo word": (PGO, PGO_OK.replace("Hi 1 9 3", "Hi 1 9"), r"line 13: expected '<word>"),
    "pgo outside": (PGO, PGO_OK.replace("7 etc", "12 etc"),
                    r"line 16: phoneme at frame 12, outside its word's frames 1..9"),
    "pgo word order": (PGO, PGO_OK.replace("Hi 1 9 3", "Hi 9 1 3"), r"ends \(frame 1\) before"),
    "pgo phoneme order": (PGO, PGO_OK.replace("6 E", "8 E"), r"line 16: phoneme at frame 7 comes"),
}  # fmt: skip


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_inputs_give_one_format_error_naming_file_and_place(tmp_path, case):
    name, text, match = BAD[case]
    path = write(tmp_path, name, text)
    with pytest.raises(FormatError, match=match) as info:
        read_cues(path, fps=24)
    assert str(info.value).startswith(f"{path}") and "\n" not in str(info.value)


def test_a_truncated_papagayo_file_names_where_it_ends(tmp_path):
    lines = PGO_OK.splitlines()
    for n in range(1, len(lines) - 1):
        path = write(tmp_path, "cut.pgo", "\n".join(lines[:n]) + "\n")
        with pytest.raises(FormatError, match=rf"cut.pgo:line {n + 1}: the file ends where"):
            read_papagayo(path)


def test_missing_file_is_one_format_error(tmp_path):
    with pytest.raises(FormatError, match="cannot read"):
        read_rhubarb_tsv(tmp_path / "none.tsv")


READERS = [read_rhubarb_tsv, read_rhubarb_json, read_rhubarb_xml,
           lambda p: read_moho_dat(p, 24), read_papagayo]  # fmt: skip


def _cues_or_one_line(path: Path, which: int) -> None:
    """A FormatError of one line naming the file; or cues in time order, each shape's value
    from the table held from its time on (at one time the last cue counts), as long as the
    file says, and between the table's values at any time."""
    try:
        cues = READERS[which](path)
        track = cue_track(cues, TABLE, JAW)
    except FormatError as exc:
        text = str(exc)
        assert text.startswith(str(path)) and len(text.splitlines()) == 1, text
        assert len(exc.detail) < 400, text
        return
    times = [c.time_s for c in cues.cues]
    assert times == sorted(times) and times[0] >= 0 and math.isfinite(times[-1])
    assert track.duration == max(times[-1], cues.end_s or 0.0)
    for time, cue in {c.time_s: c for c in cues.cues}.items():
        want = 20 * TABLE.value(cue.shape, cues.vocabulary)
        assert math.degrees(track.value(time)) == pytest.approx(want), cue
    u, du = track.sample_array(np.linspace(-1.0, track.duration + 1.0, 64))
    assert (du == 0).all() and (np.degrees(u) >= 0).all() and (np.degrees(u) <= 20 + 1e-9).all()


_GOOD = [FORMS[f][1].encode() for f in ("tsv", "json", "xml", "dat", "pgo_24")]


@settings(max_examples=150)
@given(st.binary(max_size=300), st.sampled_from(range(len(READERS))))
@example(_GOOD[0], 0).via("Rhubarb TSV")
@example(_GOOD[1], 1).via("Rhubarb JSON")
@example(_GOOD[2], 2).via("Rhubarb XML")
@example(_GOOD[3], 3).via("Moho")
@example(_GOOD[4], 4).via("Papagayo")
def test_fuzz_random_bytes_only_format_errors(tmp_path_factory, data, which):
    path = tmp_path_factory.mktemp("fz") / "f"
    path.write_bytes(data)
    _cues_or_one_line(path, which)


_LINES = st.sampled_from([*PGO_OK.splitlines(), *gen.moho_dat().splitlines(), "0.05\tD",
                          "1e308 X", "-3", "", "\t\t\t\t2 AI", "<mouthCue start='0' end='1'>X",
                          '{"start": 0, "end": 1, "value": "X"}', "99999999999"])  # fmt: skip


@settings(max_examples=300)
@given(st.lists(_LINES, max_size=25), st.sampled_from(range(len(READERS))))
def test_fuzz_shuffled_lines_only_format_errors(tmp_path_factory, lines, which):
    path = tmp_path_factory.mktemp("fz") / "f"
    path.write_text("\n".join(lines), encoding="utf-8")
    _cues_or_one_line(path, which)
