"""The validation's truth: independent forward models of the planar cell and of a DH arm.

* :mod:`.model`     the cell's forward model from first principles: its own per-point code,
                    not :mod:`cell.effects` / :mod:`cell.kinematics`
* :mod:`.parts`     the effects a truth is made of (the vocabulary's nine and four from
                    outside it), their random draws and the answer the diagnosis should give
* :mod:`.campaign`  campaigns in the exchange format measured on a truth
* :mod:`.chain`     the same for a serial arm in DH (per pose, not :mod:`cell.chain`)

``tests/cell/test_truth.py`` holds the model and :mod:`cell.effects` to the same answer
(1e-9 mm) for every vocabulary effect, so a sign, unit or composition mistake in either
shows up there instead of cancelling out in ``cellctl diagnose validate``.
"""
