"""The sim-to-real diagnosis of every campaign: any serial arm measured in 3-D
(``cell/measurements.md``, Extension v1.1), and a planar (v1) campaign read as the two-joint
chain it is (:func:`cell.diagnosis.answer.as_chain`). It uses the tie rule
(:mod:`cell.diagnosis.tie`), the places (:mod:`cell.diagnosis.places`), the leave-out
yardstick (:mod:`cell.diagnosis.leaveout`), the report format and its words
(:mod:`cell.diagnosis.page`) and the validation harness (:mod:`cell.diagnosis.harness`); the
robot is :mod:`cell.kinematics`, the campaign :mod:`cell.measurements.chain`, the calibration
that follows :mod:`cell.calibration.chain`.

* :mod:`.fit`       registration (sensor frame, markers) and parameter fits, robust errors
* :mod:`.rank`      screening, candidate fits and the none / cause / unexplained decision
* :mod:`.drift`     a sensor frame (base frame: the joints' zeros) that drifts during the
                    campaign, as a rival or a reason
* :mod:`.ripple`    a ripple of more cycles than cyclic_error's on one joint, in the remainder
* :mod:`.robust`    gross outliers found on the best candidate and set aside
* :mod:`.noise`     the sensor noise from the data: rigid constellation, revisited poses
* :mod:`.report`    the ``cell-diagnosis/1`` report for chains
* :mod:`.planar`    a planar campaign read as a chain: the v1 report's figures (gap and
                    holdout per table, station lags, noise, outliers) from the chain fits
* :mod:`.html`      its HTML page
* :mod:`.validate`  blind validation trials on the independent truth (:mod:`cell.truth`)
"""
