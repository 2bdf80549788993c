"""Adapters to the outside world (PLC, joint stations, camera), each with a simulated twin."""
