"""The measurement exchange format (``cell/measurements.md``): campaigns read, checked and
written, for the planar cell (v1) and any serial chain (Extension v1.1).

* :mod:`.campaign`    v1 campaigns (model.yaml, points.csv, paths.csv), the shared table
  reader and the atomic writer; :func:`read_campaign` reads either kind
* :mod:`.chain`       chain campaigns (dh / urdf model, markers, sensor frame)
* :mod:`.chain_spec`  a chain's model.yaml as data
* :mod:`.folder`      a campaign folder written atomically, never deleting what it did not write
* :mod:`.checked`     model files checked without pydantic when plainly valid, with it otherwise
* :mod:`.plainyaml`   model.yaml read without PyYAML when plainly written, with it otherwise

The names most callers need are importable from here.
"""
from cell.measurements.campaign import (CHAIN_KINEMATICS, FORMAT, PATH_COLUMNS, POINT_COLUMNS,
                                        Campaign, CameraSpec, CampaignFormatError, ModelSpec,
                                        check_places, pydantic_models, read_campaign,
                                        write_campaign, yaml_loc)
from cell.measurements.folder import MANIFEST, FolderNotEmptyError, staged_dir

__all__ = ["CHAIN_KINEMATICS", "FORMAT", "MANIFEST", "PATH_COLUMNS", "POINT_COLUMNS", "Campaign",
           "CameraSpec", "CampaignFormatError", "FolderNotEmptyError", "ModelSpec", "check_places",
           "pydantic_models", "read_campaign", "staged_dir", "write_campaign", "yaml_loc"]
