"""The central ENNC-QL learner process: experience intake, policy state, phase-1 fits, evaluation, checkpoints."""
