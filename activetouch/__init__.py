"""activetouch: recognise objects by touch with a ReFlex hand and MCTS pose selection."""

__version__ = "0.1.0"
