"""Where to grasp next: the observation model p(z'|z,a,y), the MCTS planner and its
greedy / random baselines."""
