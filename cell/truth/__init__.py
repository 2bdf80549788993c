"""The validation's truth: an independent forward model of the planar cell.

* :mod:`.model`     the cell's forward model from first principles: its own per-point code,
                    not :mod:`cell.effects` / :mod:`cell.kinematics`
* :mod:`.parts`     the effects a truth is made of (the vocabulary's nine and four from
                    outside it), their random draws and the answer the diagnosis should give
* :mod:`.campaign`  campaigns in the exchange format measured on a truth

``tests/cell/test_truth.py`` holds the model and :mod:`cell.effects` to the same answer
(1e-9 mm) for every vocabulary effect, so a sign, unit or composition mistake in either
shows up there instead of cancelling out in ``cellctl diagnose validate``.
"""
