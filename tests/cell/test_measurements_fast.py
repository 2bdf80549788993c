"""cell.measurements reads a campaign without pydantic when the input is plainly valid: the
hand check of model.yaml and the column-at-a-time CSV conversion must give what the
pydantic model and the cell-by-cell reading give, and leave everything else to them."""
import subprocess
import sys

import numpy as np
import pytest
from pydantic import ValidationError

from cell.measurements import FORMAT, CameraSpec, ModelSpec
from cell.measurements import campaign as m

PLAIN = [
    {"format": FORMAT, "l1_mm": 325, "l2_mm": 275.5},
    {"format": FORMAT, "kinematics": "scara", "l1_mm": 500.0, "l2_mm": 500.0,
     "command_unit_deg": 0.01, "joint_limits_deg": [[-170, 170], [-150.0, 150]],
     "camera": {"center_mm": [300, 150.25]}, "stations": ["j2", "j1"]},
]
NOT_PLAIN = [  # accepted by pydantic's conversions, or refused with its message
    {"format": FORMAT, "l1_mm": "325", "l2_mm": 275},
    {"format": FORMAT, "l1_mm": 325, "l2_mm": 275, "camera": {"center_mm": ["1", 2]}},
    {"format": FORMAT, "l1_mm": -1, "l2_mm": 275},
    {"format": FORMAT, "l1_mm": float("nan"), "l2_mm": 275},
    {"format": FORMAT, "l1_mm": 325, "l2_mm": 275, "l3_mm": 1},
    {"format": FORMAT, "l1_mm": 325},
    {"format": FORMAT, "l1_mm": True, "l2_mm": 275},
    {"format": FORMAT, "l1_mm": 325, "l2_mm": 275, "stations": ["j1", 2]},
    {"format": FORMAT, "l1_mm": 325, "l2_mm": 275, "joint_limits_deg": [[1, 2, 3]]},
    {"format": FORMAT, "l1_mm": 325, "l2_mm": 275, "camera": {"center_mm": [1, 2], "x": 0}},
    {"format": FORMAT, "l1_mm": 10 ** 400, "l2_mm": 275},
    {"format": FORMAT, "l1_mm": 325, "l2_mm": 275, "joint_limits_deg": [[0, -10 ** 400]]},
]


def by_pydantic(data):
    """The dict the pydantic model makes of ``data``, or its first error."""
    try:
        return ModelSpec._from_pydantic(m.pydantic_models()[0].model_validate(data))
    except ValidationError as exc:
        return exc.errors()[0]["type"], exc.errors()[0]["loc"]


def mine(data):
    try:
        return vars(ModelSpec.model_validate(data))
    except ValidationError as exc:
        return exc.errors()[0]["type"], exc.errors()[0]["loc"]


@pytest.mark.parametrize("data", PLAIN + NOT_PLAIN)
def test_model_spec_is_what_the_pydantic_model_says(data):
    assert mine(data) == by_pydantic(data)


def test_plain_input_takes_the_hand_check():
    assert all(m._plain(d) is not None for d in PLAIN)
    assert all(m._plain(d) is None for d in NOT_PLAIN)


def test_keyword_construction_converts_and_refuses_as_before():
    s = ModelSpec(format=FORMAT, l1_mm=325, l2_mm="275", camera=CameraSpec(center_mm=[1, 2]))
    assert s.l2_mm == 275.0 and s.camera.center_mm == (1.0, 2.0)
    with pytest.raises(ValidationError):
        ModelSpec(format=FORMAT, l1_mm=0, l2_mm=275)
    with pytest.raises(ValidationError):
        CameraSpec(center_mm=[1, 2, 3])
    assert s.model_dump(exclude_none=True, mode="json") == \
        m.pydantic_models()[0].model_validate(s.model_dump()).model_dump(exclude_none=True, mode="json")


@pytest.mark.parametrize("body", ["1,0.5,10,20,1.5,2.5,1,-1,20.0,0.5,fit\n"
                                  "2, 1e-3 ,11,21,1.5,2.5,-1,1,21,0,holdout\n\n",
                                  "1,0.5,10,20,1.5,2.5,1,-1,20.0,0.5,fit\n2,1,nan,21,1,2,1,1,21,0,fit\n",
                                  "1,0.5,10,20,1.5,2.5,1,-1,20.0,0.5,fit\n2,1,11,21,1,2,0,1,21,0,fit\n",
                                  "1.5,0.5,10,20,1.5,2.5,1,-1,20.0,0.5,fit\n",
                                  "1,0.5,10,20,1.5,2.5,1,-1,20.0,0.5,test\n",
                                  "1,0.5,10,20,1.5,2.5,1,-1,20.0,0.5\n",
                                  f"{2 ** 53 + 1},0,10,20,1,2,1,1,20,0,fit\n{2 ** 53},1,11,20,1,2,1,1,20,0,fit\n"
                                  f"{-2 ** 63},1,11,20,1,2,1,1,20,0,fit\n",
                                  "2.0,0,10,20,1,2,1,1,20,0,fit\n1e3,1,11,20,1,2,1,1,20,0,fit\n",
                                  f"{2 ** 63},0,10,20,1,2,1,1,20,0,fit\n",
                                  f"1,0,10,20,1{'0' * 400},2,1,1,20,0,fit\n"])
def test_column_reading_is_the_cell_reading(tmp_path, body):
    f = tmp_path / "points.csv"
    f.write_text("sample,time_s,j1_deg,j2_deg,x_mm,y_mm,j1_dir,j2_dir,temp_c,payload_kg,split\n" + body)

    def read(at_once: bool):
        try:
            cols, lines = m._read_table(f, m.POINT_COLUMNS, at_once)
            return {k: (v.dtype, v.tolist()) for k, v in cols.items()}, lines
        except m.CampaignFormatError as exc:
            return str(exc)
    assert read(True) == read(False)


def test_reading_a_campaign_loads_no_pydantic(tmp_path):
    d = tmp_path / "c"
    d.mkdir()
    (d / "model.yaml").write_text(f"format: {FORMAT}\nl1_mm: 325\nl2_mm: 275\n")
    (d / "points.csv").write_text("sample,time_s,j1_deg,j2_deg,x_mm,y_mm\n1,0,10,20,1,2\n"
                                  "2,1,11,22,1,2\n")
    code = (f"import sys; from cell.measurements import read_campaign; "
            f"read_campaign({str(d)!r}); print('pydantic' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
