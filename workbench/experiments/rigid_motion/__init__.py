"""The paper's rigid-motion test (Fig 6): ``scenes`` (the beam on its stage and its truth), ``run`` (render,
measure, score), ``case`` (one study or gate case).
"""
