"""Robots are data files (cell/robots/*.yaml): the cell's SCARAs and two serial arms, read
and checked when the package loads."""
from __future__ import annotations

import numpy as np
import pytest

from cell.errors import ConfigError
from cell.kinematics import Scara
from cell.kinematics import forward
from cell.measurements.chain import build_chain, load_spec
from cell.robots import CHAIN_MODELS, PRESETS, chain_model_file, load_scara
from cell.truth import chain as truth
from cell.truth.chain_campaign import UR5


def test_the_scaras_come_from_their_files_with_the_seeds_numbers():
    # seed 000: l1 = l2 = 500 mm, unit 0.01 deg; seed 002: 200 mm links, tool z -50 mm
    assert (PRESETS["seed000"].l1_mm, PRESETS["seed000"].l2_mm) == (500.0, 500.0)
    assert PRESETS["seed000"].unit == (0.01,) * 4
    assert (PRESETS["seed002"].l1_mm, PRESETS["seed002"].tool_z_mm) == (200.0, -50.0)
    assert Scara.preset("seed000").fk_planar(0.0, 0.0) == pytest.approx([1000.0, 0.0])


@pytest.mark.parametrize("name", sorted(CHAIN_MODELS))
def test_every_chain_robot_file_reads_as_a_chain_model(name):
    path = chain_model_file(name)
    chain = build_chain(load_spec(path), path)
    assert chain.n_joints == 6
    tips, _ = forward(chain, np.zeros((1, 6)))
    assert np.all(np.isfinite(tips))


def test_the_ur5_file_agrees_with_the_independent_truths_ur5():
    # cell/truth/chain_campaign.py writes UR5 from Universal Robots' published numbers on
    # its own; the robot file must put the tool at the same place for any joints
    path = chain_model_file("ur5")
    chain = build_chain(load_spec(path), path)
    q = np.random.default_rng(3).uniform(-180, 180, (20, 6))
    tips, _ = forward(chain, q)
    want = [truth.tool_points(UR5, qp, False, (0.0, 0.0, 0.0), np.zeros((1, 3)), {}, 0, 1)[0]
            for qp in q]
    assert tips[:, :3, 3] == pytest.approx(np.array(want), abs=1e-9)


def test_a_bad_robot_file_is_refused_naming_file_and_field(tmp_path):
    f = tmp_path / "bad.yaml"
    f.write_text("kinematics: scara\nname: bad\nl1_mm: -5\nl2_mm: 200\n")
    with pytest.raises(ConfigError, match=r"bad\.yaml: l1_mm: Input should be greater than 0"):
        load_scara(f)
    f.write_text("kinematics: dh\n")
    with pytest.raises(ConfigError, match="not a SCARA robot file"):
        load_scara(f)
