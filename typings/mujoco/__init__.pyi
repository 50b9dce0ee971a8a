# mujoco's bindings are compiled (pybind11) and ship no type stubs, so the checker cannot see
# MjModel, MjData, mj_step and the rest; this stub types every name of the package as Any.
from typing import Any

def __getattr__(name: str) -> Any: ...
