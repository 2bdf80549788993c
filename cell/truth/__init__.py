"""The validation's truth: independent forward models of the planar cell and of a DH arm,
the campaigns measured on them, written as files in the exchange format, and the verdict
on a diagnosis of them.

* :mod:`.model`          the cell's forward model from first principles (per point, ``math``)
* :mod:`.parts`          the effects a truth is made of (the vocabulary's nine and five from
                         outside it), their random draws and the answer the diagnosis should give
* :mod:`.campaign`       planar campaigns (seed 000 robot; uniform or clustered at stations)
* :mod:`.chain`          the same model for a serial arm in DH (per pose)
* :mod:`.chain_campaign` chain campaigns (a UR5 and a tracker)
* :mod:`.files`          the truth's own writer of model.yaml and the CSV tables
* :mod:`.verdict`        right / ambiguous / ambiguous, truth missing / unexplained / wrong

Nothing here imports the fitter's side (diagnosis, chain, calibration, :mod:`cell.effects`,
the plant, the presets, compensation, the campaign reader/writer):
``tests/cell/test_truth_independence.py`` scans every module. The truth follows the
conventions of ``cell/measurements.md``; ``tests/cell/test_truth.py`` holds the planar model
and :mod:`cell.effects` to the same answer (1e-9 mm) for every vocabulary effect, so a
sign, unit or composition mistake in either shows up there too.
"""
