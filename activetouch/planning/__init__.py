"""Where to grasp next: the training grid, the observation model p(z'|z,a,y), the MCTS planner
with its greedy / random baselines and the mesh lookahead; motion/ turns an object-frame wrist
pose into joint motion."""
