"""One part's cycle: the runner that takes a part from approach to the logged result
(:mod:`.runner`) and the cell's state machine the PLC reads (:mod:`.statemachine`).

Nothing is imported here, so that the recipes and the devices can use a part of the cycle
without loading the rest.
"""
