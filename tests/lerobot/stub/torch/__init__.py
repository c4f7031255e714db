"""Not PyTorch: the one name LeRobot's robot classes take from it.

`lerobot/types.py` writes `PolicyAction = torch.Tensor`, a type alias, and nothing on the path from
`KochFollower` to the serial port calls torch. Installing the real package would add gigabytes to
the tests for an alias; this stands in for it on `sys.path` in these tests only (conftest.py), so
LeRobot's own code runs unchanged. A LeRobot that starts to call torch on this path fails here
with an AttributeError, which is the signal to install the real one.
"""


class Tensor:
    """Stands for `torch.Tensor` in type aliases."""
