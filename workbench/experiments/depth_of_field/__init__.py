"""Depth of field (Fig 4): an oblique speckled plate through a Scheimpflug-tilted and an untilted sensor (``run``).
"""
