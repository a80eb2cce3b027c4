"""The converters added with issue 37 (ctu_motoman, keti_panda, rokae_lm, rokae_dho) on synthetic files of each set's
layout: what is converted is what was written (units, joint order, rows kept and dropped), and a file of another
layout is refused in one line. The sets' own files stay out of the repository (no licence); the arms here are the
sets' nominal models (bench/realdata/robots) with a perturbation, simulated with the bench's forward model.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import scipy.io

from bench.realdata import ctu_motoman, keti_panda, rokae, run
from bench.realdata.common import DataError, dh_points
from config.robots import load_robot

NOISE = 2e-5  # m per axis
ROBOTS = Path("bench/realdata/robots")


def simulate(robot: str, q: np.ndarray, rng: np.random.Generator, tool=(0.01, -0.02, 0.1)) -> np.ndarray:
    """Points (m) of a perturbed copy of a bench nominal at joints ``q`` (rad), in a tracker frame 3 m away."""
    nominal = load_robot(ROBOTS / f"{robot}.yaml").nominal
    table = nominal.dh_table() + rng.normal(0, [1e-3, 5e-4, 5e-4, 1e-3], (len(q[0]), 4))
    base = np.eye(4)
    base[:3, :3] = [[0, -1, 0], [1, 0, 0], [0, 0, 1]]
    base[:3, 3] = [3.0, -1.0, 0.5]
    return dh_points(table, nominal.joint_types, base, np.array(tool), q) + rng.normal(0, NOISE, (len(q), 3))


# --- ctu_motoman: MATLAB 'dataset', 26 columns, several records per pose, NaN where the tracker logged nothing ----

def write_motoman(folder: Path, rng: np.random.Generator, torso: float = 1e-4) -> tuple[np.ndarray, np.ndarray]:
    poses = 20
    q = rng.uniform(-1, 1, (poses, 6))
    points = simulate("motoman_right_arm", q, rng)
    records = []
    for k in range(poses):
        for face in (1, 2):  # two camera records of every pose; the converter keeps the first
            row = np.zeros(26)
            row[0], row[1], row[2] = 100 + k, face, 1
            row[6] = torso
            row[7:13] = q[k]
            row[13:19] = rng.uniform(-1, 1, 6)  # the left arm: not used
            row[19:22] = points[k] if k != 5 else np.nan  # pose 5: not logged by the tracker
            row[22:26] = 7e-6
            records.append(row)
    folder.mkdir(parents=True, exist_ok=True)
    scipy.io.savemat(folder / ctu_motoman.FILE, {"dataset": np.array(records)})
    logged = np.delete(np.arange(poses), 5)
    kept = np.delete(logged, ctu_motoman.DROPPED)  # as the source's loader: its 13th logged pose removed
    return q[kept], points[kept]


def test_motoman_converter_keeps_the_first_record_of_each_logged_pose(tmp_path: Path) -> None:
    q, points = write_motoman(tmp_path / "ctu_motoman", np.random.default_rng(1))
    data = ctu_motoman.convert(tmp_path / "ctu_motoman")
    assert data.joints == "RRRRRR" and len(data.q) == 18
    assert np.array_equal(data.q, q) and np.array_equal(data.points, points)
    assert np.array_equal(np.flatnonzero(data.check), [3, 7, 11, 15]) and np.all(data.joint == 0)
    write_motoman(tmp_path / "turned", np.random.default_rng(1), torso=0.1)  # 0.1 mrad is taken as 0, 0.1 rad not
    with pytest.raises(DataError, match=r"the torso axis E moves by 1\.00e-01 rad"):
        ctu_motoman.convert(tmp_path / "turned")
    scipy.io.savemat(tmp_path / "turned" / ctu_motoman.FILE, {"dataset": np.zeros((3, 20))})
    with pytest.raises(DataError, match=r"is \(3, 20\), expected 26 columns"):
        ctu_motoman.convert(tmp_path / "turned")


# --- keti_panda: whitespace table, 7 joints (deg) then X Y Z (m), one file per arm -------------------------------

def test_panda_converter_reads_degrees_and_metres_per_arm(tmp_path: Path) -> None:
    rng = np.random.default_rng(2)
    folder = tmp_path / "keti_panda"
    folder.mkdir()
    truth = {}
    for arm in keti_panda.ARMS:
        q = rng.uniform(-1.5, 1.5, (12, 7)) + np.radians([0, 0, 0, -90, 0, 90, 0])
        points = simulate("franka_panda", q, rng)
        lines = ["\t".join(f"{float(v)!r}" for v in [*np.degrees(row), *p]) + "\t"
                 for row, p in zip(q, points, strict=True)]
        (folder / f"panda_{arm}.txt").write_text("\n".join(lines) + "\n")
        truth[arm] = q, points
    for source in keti_panda.SOURCES:
        data = source.convert(folder)
        q, points = truth[source.name.rsplit("_", 1)[1]]
        assert data.joints == "RRRRRRR" and np.allclose(data.q, q, atol=1e-12) and np.array_equal(data.points, points)
        assert np.array_equal(np.flatnonzero(data.check), [3, 7, 11])
    (folder / "panda_top.txt").unlink()
    with pytest.raises(DataError, match=r"panda_top\.txt: missing \(see"):
        keti_panda.SOURCES[2].convert(folder)
    (folder / "panda_top.txt").write_text("1 2 3\n")
    with pytest.raises(DataError, match="3 columns, expected 10"):
        keti_panda.SOURCES[2].convert(folder)


# --- rokae_lm: controller jointtargets (deg) + tracker export (nominal and measured blocks, mm) ------------------

def write_rokae_lm(folder: Path, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    q = rng.uniform(-1, 1, (8, 6))
    points = simulate("rokae_lm_pytorch", q, rng)
    folder.mkdir(parents=True, exist_ok=True)
    joints = [f"LOCAL VAR jointtarget j{k + 1} = j:{{{','.join(repr(float(v)) for v in np.degrees(row))}\t\t ,0\t}}\t\t"
              "{EJ 0,0,0,0,0,0}" for k, row in enumerate(q)]
    (folder / "joint_angle.csv").write_text("\n".join(joints) + "\n")
    nominal = points + 0.002  # the tracker software's nominal block: not what was measured
    laser = [f"Motion{k + 1} " + " ".join(f"{v:.4f}" for v in [*n * 1e3, 170, -60, -20, *p * 1e3, 170, -60, -20,
                                                                 0.19, 0.03])
             for k, (n, p) in enumerate(zip(nominal, points, strict=True))]
    (folder / "laser_pos.csv").write_text("\n".join(laser) + "\n")
    return q, points


def test_rokae_lm_converter_reads_the_measured_block(tmp_path: Path) -> None:
    q, points = write_rokae_lm(tmp_path / "rokae_lm", np.random.default_rng(3))
    data = rokae.convert_lm(tmp_path / "rokae_lm")
    assert np.allclose(data.q, q, atol=1e-12) and np.allclose(data.points, points, atol=1e-7)  # 0.0001 mm printed
    with (tmp_path / "rokae_lm" / "laser_pos.csv").open("a") as extra:
        extra.write("Motion9 1 2 3\n")
    with pytest.raises(DataError, match="8 joint targets and 8 of 9 tracker lines"):
        rokae.convert_lm(tmp_path / "rokae_lm")


# --- rokae_dho: '#angle' (deg), '#location' (mm), '#pos' blocks separated by '--------' -------------------------

def write_rokae_dho(folder: Path, rng: np.random.Generator, poses: int = 30) -> tuple[np.ndarray, np.ndarray]:
    q = rng.uniform(-1, 1, (poses, 6))
    q[0, 0] = -0.5  # a line that starts with a minus sign is a reading, not a separator
    points = simulate("rokae_dh_optimize", q, rng)
    folder.mkdir(parents=True, exist_ok=True)
    text = ["#angle: q1,q2,q3,q4,q5,q6,", *(",".join(repr(float(v)) for v in np.degrees(r)) for r in q), "--------",
            "#location: x,y,z", *(",".join(repr(float(v)) for v in p * 1e3) for p in points), "--------",
            "#pos: qx qy qz qw", *("0.5,0.5,0.5,0.5" for _ in q)]
    (folder / "data.txt").write_text("\n".join(text) + "\n")
    return q, points


def test_rokae_dho_converter_reads_the_blocks(tmp_path: Path) -> None:
    q, points = write_rokae_dho(tmp_path / "rokae_dho", np.random.default_rng(4), poses=9)
    data = rokae.convert_dho(tmp_path / "rokae_dho")
    assert np.allclose(data.q, q, atol=1e-12) and np.allclose(data.points, points, atol=1e-12)
    (tmp_path / "rokae_dho" / "data.txt").write_text("#angle: q\n1,2,3,4,5,6\n--------\n#location: x\n1,2\n")
    with pytest.raises(DataError, match="expected '#angle' rows of 6"):
        rokae.convert_dho(tmp_path / "rokae_dho")


def test_bench_on_rokae_dho_layout_places_the_nominal_and_calibrates(tmp_path: Path) -> None:
    """The pipeline on a free-pose set with a bench nominal: the perturbed arm's nominal, placed, misses by the
    perturbation; the product and the DH-only fit get to the noise on the held-out rows."""
    write_rokae_dho(tmp_path / "rokae_dho", np.random.default_rng(5))
    (result,) = run.run_set("rokae_dho", tmp_path / "rokae_dho", tmp_path, regions=False)
    rows = {r.model: r for r in result.rows}
    plain, base = rows["product plain"], rows["DH-only least squares"]
    assert base.check < 3 * NOISE * np.sqrt(3) and plain.check <= run.BASELINE_TARGET * base.check
    assert rows["nominal, base and tools fitted"].check > 10 * base.check  # the perturbation (about 1 mm, 1 mrad)
    assert "in-sample" in rows["published"].note
