"""Run one of MAVSDK-Python's examples unchanged: ``python run_grpc_example.py FILE``.

Why: the examples ``import mavsdk`` (the gRPC API of MAVSDK-Python up to 3.x); that API
now ships as ``mavsdk_grpc``, and ``mavsdk`` 4.x is the native binding. Every import of
``mavsdk`` or ``mavsdk.X`` is given the module ``mavsdk_grpc`` or ``mavsdk_grpc.X``
itself (one module object under both names: protobuf descriptors are registered once).
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import runpy
import sys
from types import ModuleType


class _Alias(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    def find_spec(self, fullname: str, path=None, target=None):
        if fullname == "mavsdk" or fullname.startswith("mavsdk."):
            return importlib.util.spec_from_loader(fullname, self)
        return None

    def create_module(self, spec) -> ModuleType:
        return importlib.import_module("mavsdk_grpc" + spec.name[len("mavsdk"):])

    def exec_module(self, module: ModuleType) -> None:
        pass  # imported already, under its own name


def main(path: str) -> None:
    sys.meta_path.insert(0, _Alias())
    sys.argv = [path]
    runpy.run_path(path, run_name="__main__")


if __name__ == "__main__":
    main(sys.argv[1])
