"""Design a Scheimpflug stereo rig before it is built (``workbench design``): inputs, the face, candidate rigs and the
hinge rule, the instrument's prediction, the search, the verification by rendering, the report (:mod:`.run`)."""
