"""The paper's calibration (Table 1, Fig 5): ``views`` (rendered board views and their truth), ``run`` (the
protocol, scored against the true rig), ``agreement`` (render <-> camera-model agreement at every corner).
"""
