"""Hostile text input (issue #10): encodings, repeated keys, recursive aliases and alias bombs, exponent floats,
files that are not regular files, and convert-log options. Every failure is kincal's own one-line error."""

import codecs
import os

import numpy as np
import pytest

from kincal import robots
from kincal.errors import DataFormatError
from kincal.io.logs import convert_log
from kincal.io.models import dump_robot, load_robot, parse_robot
from kincal.io.yamlfile import parse_yaml, read_text, read_yaml


def _one_line(exc_info):
    assert "\n" not in str(exc_info.value)


@pytest.mark.parametrize("prefix, encoding", [(b"", "utf-8"), (codecs.BOM_UTF8, "utf-8"),
                                              (codecs.BOM_UTF16_LE, "utf-16-le"), (codecs.BOM_UTF16_BE, "utf-16-be")])
def test_utf8_and_utf16_with_their_marks_are_read(tmp_path, prefix, encoding):
    p = tmp_path / "f.yaml"
    p.write_bytes(prefix + "name: café\nx: 1\n".encode(encoding))
    assert read_yaml(p, "test file") == {"name": "café", "x": 1}


def test_text_that_is_not_utf8_names_the_byte_offset(tmp_path):
    p = tmp_path / "latin1.yaml"
    p.write_bytes("# caf\xe9\nx: 1\n".encode("latin-1"))
    with pytest.raises(DataFormatError, match=r"latin1\.yaml: not UTF-8 text: byte 0xe9 at offset 5") as e:
        read_text(p, "test file")
    _one_line(e)


def test_only_regular_files_are_read(tmp_path):
    with pytest.raises(DataFormatError, match="not a regular file"):
        read_text(tmp_path, "model file")
    if os.path.exists("/dev/zero"):
        with pytest.raises(DataFormatError, match="not a regular file"):
            read_text("/dev/zero", "model file")


def test_a_repeated_key_is_an_error_not_the_last_one_winning():
    with pytest.raises(DataFormatError, match=r"job\.yaml: not valid YAML \(line 2, column 1\): key 'free' appears "
                                              r"twice in one mapping \(first on line 1\)") as e:
        parse_yaml("free: offsets\nfree: kinematic\n", "job.yaml")
    _one_line(e)


def test_a_recursive_alias_is_refused_at_load():
    text = dump_robot(robots.load("ur10"))
    assert "\nmeta:" in text
    text = text.replace("\nmeta:", "\nmeta: &m\n  self: *m\n  was:", 1)
    with pytest.raises(DataFormatError, match="recursive value") as e:
        parse_robot(text, "m.yaml")
    _one_line(e)


def test_an_alias_bomb_is_refused_quickly():
    levels = ["a0: &a0 [x, x, x, x, x, x, x, x, x, x]"]
    levels += [f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]" for i in range(1, 9)]
    with pytest.raises(DataFormatError, match="expands to more than"):
        parse_yaml("\n".join(levels) + "\n", "bomb.yaml")


def test_shared_values_through_aliases_still_load():
    frida = load_robot("frida")  # the built-in file shares one joint list between its arms with an alias
    assert frida["left"].dof == frida["right"].dof == 7
    assert parse_yaml("a: &j [1, 2]\nb: *j\n", "f.yaml") == {"a": [1, 2], "b": [1, 2]}


def test_exponent_floats_are_numbers():
    assert parse_yaml("rank_rtol: 1e-7\nbig: 2E+3\nneg: -.5e1\nword: e5\n", "f.yaml") == {
        "rank_rtol": 1e-7, "big": 2e3, "neg": -5.0, "word": "e5"}


@pytest.mark.parametrize("option, value, match", [
    ("still_rad_s", float("nan"), "--still-rad-s: expected a finite number > 0"),
    ("still_rad_s", -1.0, "--still-rad-s: expected a finite number > 0"),
    ("period_s", 0.0, "--period-s: expected a finite number > 0"),
    ("period_s", -0.004, "--period-s: expected a finite number > 0"),
    ("every", 0, "--every: expected an integer >= 1"),
])
def test_convert_log_options_are_checked(tmp_path, option, value, match):
    log = tmp_path / "log.csv"
    log.write_text("t," + ",".join(f"arm.c{i + 1}" for i in range(6)) + "\n" + "0.0," + ",".join(["0"] * 6) + "\n")
    with pytest.raises(DataFormatError, match=match):
        convert_log(log, robots.load("ur10"), ("arm",), **{option: value})


def test_per_stop_on_a_log_without_a_stop_says_so(tmp_path):
    ur = robots.load("ur10")
    n = ur["arm"].dof
    t = np.arange(200) * 0.004
    motor = np.outer(t, np.arange(1, n + 1)) * 50.0  # always moving fast
    log = tmp_path / "moving.csv"
    log.write_text("t," + ",".join(f"arm.c{i + 1}" for i in range(n)) + "\n"
                   + "\n".join(",".join(repr(float(x)) for x in [ti, *row]) for ti, row in zip(t, motor)) + "\n")
    with pytest.raises(DataFormatError, match="no sample is still") as e:
        convert_log(log, ur, ("arm",), still_rad_s=1e-3, per_stop=True)
    _one_line(e)


@pytest.mark.parametrize("text, ok", [("1.5", True), ("-2e-3", True), (".5", True), ("7.", True), ("+3E+2", True),
                                      ("3_0_4", False), ("\u0663", False), ("nan", False), ("inf", False),
                                      ("1e999", False), ("0x10", False), ("", False), ("1,5", False)])
def test_numbers_are_plain_decimal_or_scientific(text, ok):
    from kincal.io.units import plain_number

    assert (plain_number(text) is not None) == ok


def test_a_csv_cell_with_underscores_is_refused(tmp_path):
    from kincal.io.datasets import load_dataset, write_dataset
    from kincal.simulate import generate_pose

    ur = robots.load("ur10")
    ds, _, _ = generate_pose(ur, None, n=5, rng=0)
    manifest = write_dataset(ds, tmp_path / "d.yaml", ur, model="ur10")
    csv_path = manifest.with_suffix(".csv")
    lines = csv_path.read_text().splitlines()
    cells = lines[2].split(",")
    cells[0] = "3_0_4"
    lines[2] = ",".join(cells)
    csv_path.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError, match=r"line 3, column '.*': expected a number, found '3_0_4'"):
        load_dataset(manifest)


def test_escapes_beyond_unicode_and_nul_in_file_names_are_kincal_errors(tmp_path):
    with pytest.raises(DataFormatError, match="not valid YAML"):
        parse_yaml('a: "\\U100010000"\n', "f.yaml")
    with pytest.raises(DataFormatError, match="contains a NUL character"):
        read_text(tmp_path / "a\0b.yaml", "data set manifest")


def test_a_file_name_with_a_newline_stays_on_one_line(tmp_path):
    """Found by the 2000-example job fuzz: a data entry of blanks and newlines named a manifest whose error
    message broke over two lines; file names that are not printable are quoted."""
    with pytest.raises(DataFormatError) as exc:
        read_text(tmp_path / "\n\n  ", "data set manifest")
    assert "\n" not in str(exc.value) and "cannot read data set manifest: No such file" in str(exc.value)
    job = tmp_path / "job.yaml"
    job.write_text("format: kincal-job\nversion: 1\nmodel: ur10\ndata:\n- '\n\n  '\n")
    from kincal.io.jobs import load_job

    with pytest.raises(DataFormatError) as exc:
        load_job(job)
    assert "\n" not in str(exc.value)


def test_a_byte_order_mark_in_a_log_or_data_csv_keeps_the_first_column(tmp_path):
    """A BOM used to turn the header's first name into '\\ufefft': the time column was dropped silently."""
    ur = robots.load("ur10")
    log = tmp_path / "log.csv"
    rows = [f"{0.5 * k}," + ",".join("0.1" for _ in range(6)) for k in range(30)]
    log.write_bytes(codecs.BOM_UTF8 + ("t," + ",".join(f"arm.c{i + 1}" for i in range(6)) + "\n"
                                       + "\n".join(rows) + "\n").encode())
    t, _ = convert_log(log, ur, ("arm",))
    assert t[-1] == pytest.approx(14.5)  # the log's own time column, not a default period
    from kincal.io.datasets import load_dataset, write_dataset
    from kincal.simulate import generate_pose

    ds, _, _ = generate_pose(ur, None, n=5, rng=0)
    manifest = write_dataset(ds, tmp_path / "d.yaml", ur, model="ur10")
    csv_path = manifest.with_suffix(".csv")
    csv_path.write_bytes(codecs.BOM_UTF8 + csv_path.read_bytes())
    np.testing.assert_array_equal(load_dataset(manifest).q["arm"], ds.q["arm"])
