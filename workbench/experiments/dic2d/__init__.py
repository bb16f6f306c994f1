"""2-D DIC on exact synthetic images: ``case`` (the translated-speckle pair of studies and gates), ``accuracy``
(bias vs sub-pixel shift, noise floor, shape functions), ``star`` (the DIC Challenge 2.0 Star).
"""
