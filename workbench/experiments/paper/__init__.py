"""The whole paper in one command and one report (``run``): calibration, rigid motion, bending, depth of field.
"""
