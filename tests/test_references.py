"""File references in jobs and manifests (issue #10): relative to the referencing file, regular files only, no
file content echoed beyond a short quote, confined to the job's folder on request; a manifest's model checked
against the job's; an absurd measured cell and joint readings past their limits named by file, line, column."""

import os
import re
from dataclasses import replace

import numpy as np
import pytest
import yaml

from kincal.cli import main
from kincal.errors import DataFormatError
from kincal.io.csvtable import read_table
from kincal.io.datasets import load_dataset, write_dataset
from kincal.io.jobs import load_job, write_job
from kincal.io.models import save_robot
from kincal.io.yamlfile import parse_yaml
from kincal.robots import load
from kincal.simulate.generators import generate_markers
from kincal.simulate.perturb import perturb_robot


@pytest.fixture(scope="module")
def markers():
    ur10 = load("ur10")
    ds, _, _ = generate_markers(perturb_robot(ur10, "fine", rng=1), n=30, rng=3, known_markers=True)
    return ur10, ds


@pytest.fixture
def job(tmp_path, markers):
    ur10, ds = markers
    folder = tmp_path / "job"
    folder.mkdir()
    write_dataset(ds, folder / "data" / "m.yaml", ur10, model="ur10")
    return write_job(folder / "job.yaml", name="j", model="ur10", data=["data/m.yaml"])


def _edit(path, **changes):
    content = yaml.safe_load(path.read_text())
    content.update(changes)
    path.write_text(yaml.safe_dump(content))


def test_references_resolve_relative_to_their_file_not_the_working_directory(job, tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    assert load_job(job).datasets[0].size == 30
    save_robot(load("ur10"), tmp_path / "here.yaml")  # a model in the working directory only
    _edit(job, model="here.yaml")
    with pytest.raises(DataFormatError, match=r"job/here\.yaml: no such model file"):
        load_job(job)


@pytest.mark.parametrize("target", ["/dev/zero", "folder"])
def test_a_reference_to_something_not_a_regular_file_is_refused(job, target):
    if target == "folder":
        target = str(job.parent / "data")
    elif not os.path.exists(target):
        pytest.skip("no /dev/zero")
    _edit(job, data=[{"manifest": target}])
    with pytest.raises(DataFormatError, match="not a regular file"):
        load_job(job)
    manifest = job.parent / "data" / "m.yaml"
    _edit(manifest, data=target)
    with pytest.raises(DataFormatError, match="not a regular file"):
        load_dataset(manifest)


def test_errors_quote_no_more_of_a_file_than_a_short_line(job, tmp_path):
    secret = tmp_path / "secret.txt"  # a file that is not YAML mapping: read as one long string
    secret.write_text("root:x:0:0:" + "s" * 400 + "\nnext:line\n")
    _edit(job, data=[{"manifest": str(secret)}])
    with pytest.raises(DataFormatError) as e:
        load_job(job)
    assert "s" * 80 not in str(e.value) and "next" not in str(e.value) and "\n" not in str(e.value)
    _edit(job, data=[{"manifest": "data/m.yaml"}])
    csv = job.parent / "data" / "m.csv"
    lines = csv.read_text().splitlines()
    csv.write_text("\n".join([lines[0] + ",x" + "y" * 300] + [r + ",1" for r in lines[1:]]) + "\n")
    with pytest.raises(DataFormatError, match="unexpected column") as e:
        load_job(job)
    assert "y" * 80 not in str(e.value)


@pytest.mark.parametrize("how", ["dotdot", "symlink", "absolute"])
def test_confine_refuses_references_outside_the_jobs_folder(job, tmp_path, how):
    outside = tmp_path / "outside"
    outside.mkdir()
    (job.parent / "data" / "m.csv").rename(outside / "m.csv")
    manifest = job.parent / "data" / "m.yaml"
    if how == "symlink":
        (job.parent / "data" / "link.csv").symlink_to(outside / "m.csv")
    _edit(manifest, data={"dotdot": "../../outside/m.csv", "symlink": "link.csv",
                          "absolute": str(outside / "m.csv")}[how])
    assert load_job(job).datasets[0].size == 30  # not confined: any regular file
    with pytest.raises(DataFormatError, match=r"m\.yaml: data: .* resolves to .*outside/m\.csv, outside the job's "
                                              r"folder .* \(references are confined to it\)"):
        load_job(job, confine=True)
    _edit(job, confine=True)
    with pytest.raises(DataFormatError, match="outside the job's folder"):
        load_job(job)


def test_confine_on_the_command_line_and_inside_the_folder(job, tmp_path, capsys):
    assert load_job(job, confine=True).datasets[0].size == 30  # everything inside: fine
    _edit(job, data=[{"manifest": "../elsewhere.yaml"}])
    assert main(["calibrate", str(job), "-o", str(tmp_path / "out"), "--confine"]) == 2
    (line,) = capsys.readouterr().err.strip().splitlines()
    assert line.startswith("kincal: error:") and "data[0].manifest: '../elsewhere.yaml' resolves to" in line
    assert not (tmp_path / "out").exists()


def test_a_manifests_model_must_be_the_jobs(job, tmp_path):
    manifest = job.parent / "data" / "m.yaml"
    _edit(manifest, model="frida")
    with pytest.raises(DataFormatError, match=r"m\.yaml: model: 'frida' \(robot 'frida'\) is not the job's model "
                                              r"'ur10' \(robot 'ur10'\)"):
        load_job(job)
    _edit(manifest, model="missing.yaml")
    with pytest.raises(DataFormatError, match=r"m\.yaml: model: '.*missing\.yaml' is not the job's model 'ur10', "
                                              r"and it cannot be read"):
        load_job(job)
    # another model of the same robot (e.g. one calibrated before) is the same robot: accepted
    save_robot(perturb_robot(load("ur10"), "fine", rng=5), job.parent / "data" / "calibrated.yaml")
    _edit(manifest, model="calibrated.yaml")
    assert load_job(job).datasets[0].size == 30


def test_one_absurd_marker_cell_is_named_by_line_and_column(job):
    csv = job.parent / "data" / "m.csv"
    lines = csv.read_text().splitlines()
    cells = lines[7].split(",")
    head = lines[0].split(",")
    cells[head.index("m2.y")] = "1e300"
    lines[7] = ",".join(cells)
    csv.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError, match=r"m\.csv: line 8, column 'm2\.y': expected a length within [\d.e+]+ m "
                                              r"of the column's median .* found 1e\+300 m: not a measurement") as e:
        load_job(job)
    assert "\n" not in str(e.value) and "spread" not in str(e.value)


def test_joint_readings_past_their_limits_are_warned_and_past_4_pi_refused_unless_continuous(job, markers):
    csv = job.parent / "data" / "m.csv"
    lines = csv.read_text().splitlines()
    cells = lines[4].split(",")
    cells[2] = "6.5"  # arm.elbow: past the UR10's +-360 deg, within 4 pi
    lines[4] = ",".join(cells)
    csv.write_text("\n".join(lines) + "\n")
    (warning,) = [w for w in load_job(job).datasets[0].meta["warnings"] if "limit" in w]
    assert re.search(r"m\.csv: line\(s\) 5, column 'arm\.elbow': reading 6\.5 rad \(372\.4 deg\) is past the joint "
                     r"limit 6\.28319 rad \(360 deg\) of model 'ur10'", warning)
    cells[2] = "13"  # beyond 4 pi: not an angle in radians
    lines[4] = ",".join(cells)
    csv.write_text("\n".join(lines) + "\n")
    with pytest.raises(DataFormatError, match=r"line 5, column 'arm\.elbow': expected a joint angle within \+-4 pi"):
        load_job(job)
    # a continuous joint (no limits) may read any number of turns: neither warned nor refused
    ur10, ds = markers
    free = ur10.replace_arm("arm", ur10["arm"].replace(lower=np.full(6, -np.inf), upper=np.full(6, np.inf)))
    q = ds.q["arm"].copy()
    q[3, 2] = 13.0
    back = load_dataset(write_dataset(replace(ds, q={"arm": q}), job.parent / "c.yaml", free, model="ur10"), free)
    assert back.q["arm"][3, 2] == 13.0 and not any("limit" in w for w in back.meta["warnings"])


def test_yaml_and_csv_errors_cut_their_quotes_short(tmp_path):
    long = "k" * 300
    for text in (f"{long}: 1\n{long}: 2\n", f"x: *{long}\n", f"x: 1\n{long}: [\n"):
        with pytest.raises(DataFormatError) as e:
            parse_yaml(text, "f.yaml")
        assert "k" * 170 not in str(e.value) and "\n" not in str(e.value)
    csv = tmp_path / "t.csv"
    for body in (f"{long},{long}\n1,2\n", f"a,b\n1,{long}\n", f"a,{long}\n1,x\n"):
        csv.write_text(body)
        with pytest.raises(DataFormatError) as e:
            read_table(csv)
        assert "k" * 81 not in str(e.value) and "\n" not in str(e.value)


def test_confine_covers_the_jobs_model_file(job, tmp_path):
    save_robot(load("ur10"), tmp_path / "outside.yaml")
    _edit(job, model="../outside.yaml")
    assert load_job(job).robot.name == "ur10"
    with pytest.raises(DataFormatError, match=r"job\.yaml: model: '\.\./outside\.yaml' resolves to .* outside"):
        load_job(job, confine=True)
