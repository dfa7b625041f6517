"""A whitelisted serializer for run state: JSON for the structure, one npz for the arrays.

No pickle: :class:`StateEncoder` turns an object graph into a JSON tree plus named numpy arrays, and
:class:`StateDecoder` rebuilds it, constructing ONLY the classes it is given (a registry of allowed
types, looked up by name; nothing is imported or called by name from the file). Supported:

- ``None``, bool, int, float, str, numpy scalars; list, tuple, dict (any supported keys), set;
- numpy arrays (not of dtype object; a view of an array stored before is stored as its place in
  that array, so it is a view again after loading) and torch tensors (stored as numpy; dtype, device,
  ``requires_grad`` and ``nn.Parameter`` kept), ``torch.device``;
- ``numpy.random.Generator`` (PCG64 state) and ``torch.Generator`` (its state tensor);
- ``gtsam.Pose3`` / ``gtsam.Similarity3`` (rotation matrix, translation, scale as JSON floats: exact);
- objects of the registered classes, by their ``__dict__`` (dataclasses included); a class may
  register its own hooks (``encode(obj, enc) -> dict``, ``decode(data, dec) -> obj``);
- *resources*: objects of given types that are not state (the config, the flow estimator) are stored
  as the attribute path where they were first met (``pipe.cfg.graph``) and taken from a freshly
  built object on load.

Shared references are kept (an object met twice is stored once and decoded as one object), so e.g.
a random generator shared by two stages stays shared.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from typing import Any

import numpy as np

from gsslam.errors import GsslamError


class StateCodecError(GsslamError):
    """An object that cannot be stored, or a stored tree that does not decode (corrupt or foreign)."""


_PRIMITIVE = (bool, int, float, str, type(None))
_BITGEN = "PCG64"


def _qualname(cls: type) -> str:
    return f"{cls.__module__}.{cls.__qualname__}"


class StateEncoder:
    """``tree = StateEncoder(...).encode(obj)``; the arrays are in ``.arrays`` afterwards."""

    def __init__(
        self,
        classes: list[type],
        resource_types: tuple[type, ...] = (),
        hooks: dict[type, Callable[[Any, StateEncoder], dict]] | None = None,
    ) -> None:
        self.classes = {cls: _qualname(cls) for cls in classes}
        self.resource_types = resource_types
        self.hooks = hooks or {}
        self.arrays: dict[str, np.ndarray] = {}
        self._memo: dict[int, int] = {}  # id(obj) -> reference number
        self._keep: list[Any] = []  # keeps encoded objects alive so that ids stay unique
        self._whole: set[int] = set()  # ids of the arrays stored with their data (views refer to them)
        self.resources: dict[int, str] = {}  # id(resource) -> attribute path where first met

    def encode(self, o: Any, path: str = "root") -> Any:
        if isinstance(o, np.generic):  # before float: numpy.float64 is a float subclass
            return {"$": "npscalar", "dtype": o.dtype.str, "v": o.item()}
        if isinstance(o, _PRIMITIVE):
            return o
        if id(o) in self.resources:
            return {"$": "res", "name": self.resources[id(o)]}
        if isinstance(o, self.resource_types):
            if not all(part.isidentifier() for part in path.split(".")):
                raise StateCodecError(f"{type(o).__name__} at {path}: a resource must be an attribute")
            self._resource(o, path)
            return {"$": "res", "name": path}
        if id(o) in self._memo:
            return {"$": "ref", "id": self._memo[id(o)]}
        if isinstance(o, tuple):
            return {"$": "tuple", "v": [self.encode(v, f"{path}[{i}]") for i, v in enumerate(o)]}
        ref = self._remember(o)
        if isinstance(o, list):
            return {"$": "list", "id": ref, "v": [self.encode(v, f"{path}[{i}]") for i, v in enumerate(o)]}
        if isinstance(o, dict):
            keys = list(o)
            return {
                "$": "dict",
                "id": ref,
                "k": [self.encode(k, f"{path}.<key>") for k in keys],
                "v": [self.encode(o[k], f"{path}[{k!r}]") for k in keys],
            }
        if isinstance(o, (set, frozenset)):
            return {
                "$": "set",
                "id": ref,
                "v": [self.encode(v, f"{path}<item>") for v in sorted(o, key=repr)],
            }
        if isinstance(o, np.ndarray):
            view = self._view(o)
            if view is not None:  # a view of an array stored before: stored as where it looks
                return {"$": "view", "id": ref, **view}
            self._whole.add(id(o))
            u8, recipe = _as_uint8(o)
            if u8 is not None:  # an 8-bit image as float: stored as its bytes (exact, 4x smaller)
                return {"$": "nd", "id": ref, "a": self._array(u8, path), "u8": recipe}
            return {"$": "nd", "id": ref, "a": self._array(o, path)}
        if isinstance(o, np.random.Generator):
            state = o.bit_generator.state
            if state.get("bit_generator") != _BITGEN:
                raise StateCodecError(f"{path}: only {_BITGEN} generators can be stored")
            return {"$": "npgen", "id": ref, "state": state}
        special = self._torch(o, ref, path)
        if special is not None:
            return special
        gt = _gtsam_value(o)
        if gt is not None:
            return {**gt, "id": ref}
        cls = type(o)
        if cls not in self.classes:
            raise StateCodecError(f"cannot store an object of type {_qualname(cls)} (at {path})")
        if cls in self.hooks:
            return {"$": "obj", "cls": self.classes[cls], "id": ref, "hook": self.hooks[cls](o, self)}
        state = {k: self.encode(v, f"{path}.{k}") for k, v in vars(o).items()}
        return {"$": "obj", "cls": self.classes[cls], "id": ref, "state": state}

    def _resource(self, o: Any, path: str) -> None:
        """Name ``o`` and the resources among its attributes (a config's sections) by their paths."""
        self.resources[id(o)] = path
        for k, v in getattr(o, "__dict__", {}).items():
            if isinstance(v, self.resource_types) and id(v) not in self.resources:
                self._resource(v, f"{path}.{k}")

    def _remember(self, o: Any) -> int:
        ref = len(self._memo)
        self._memo[id(o)] = ref
        self._keep.append(o)
        return ref

    def _view(self, a: np.ndarray) -> dict | None:
        """``{of, offset, shape, strides}`` when ``a`` views an array stored whole earlier, else None."""
        base = a.base
        if not isinstance(base, np.ndarray) or id(base) not in self._whole or base.dtype != a.dtype:
            return None
        offset = a.__array_interface__["data"][0] - base.__array_interface__["data"][0]
        return {
            "of": self._memo[id(base)],
            "offset": offset,
            "shape": list(a.shape),
            "strides": list(a.strides),
        }

    def _array(self, a: np.ndarray, path: str) -> str:
        if a.dtype.hasobject:
            raise StateCodecError(f"{path}: arrays of Python objects cannot be stored")
        name = f"a{len(self.arrays)}"
        self.arrays[name] = a
        return name

    def _torch(self, o: Any, ref: int, path: str) -> dict | None:
        torch = _torch_module()
        if torch is None:
            return None
        if isinstance(o, torch.Tensor):
            return {
                "$": "tensor",
                "id": ref,
                "a": self._array(o.detach().cpu().numpy(), path),
                "device": str(o.device),
                "grad": bool(o.requires_grad),
                "param": isinstance(o, torch.nn.Parameter),
            }
        if isinstance(o, torch.device):
            return {"$": "device", "id": ref, "v": str(o)}
        if isinstance(o, torch.Generator):
            return {"$": "tgen", "id": ref, "a": self._array(o.get_state().numpy(), path)}
        return None


class StateDecoder:
    """``obj = StateDecoder(classes, arrays, resolve).decode(tree)``.

    ``resolve(name)`` returns the resource stored under ``name`` (from a freshly built object).
    """

    def __init__(
        self,
        classes: list[type],
        arrays: dict[str, np.ndarray],
        resolve: Callable[[str], Any],
        hooks: dict[type, Callable[[dict, StateDecoder], Any]] | None = None,
    ) -> None:
        self.classes = {_qualname(cls): cls for cls in classes}
        self.arrays = arrays
        self.resolve = resolve
        self.hooks = hooks or {}
        self._memo: dict[int, Any] = {}

    def decode(self, node: Any) -> Any:
        try:
            return self._decode(node)
        except StateCodecError:
            raise
        except (KeyError, TypeError, ValueError, IndexError, AttributeError) as e:
            raise StateCodecError(f"the stored state does not decode ({type(e).__name__}: {e})") from e

    def _decode(self, node: Any) -> Any:
        if isinstance(node, _PRIMITIVE):
            return node
        if not isinstance(node, dict) or "$" not in node:
            raise StateCodecError(f"unexpected node {str(node)[:60]!r} in the stored state")
        kind = node["$"]
        if kind == "npscalar":
            return np.dtype(node["dtype"]).type(node["v"])
        if kind == "res":
            return self.resolve(node["name"])
        if kind == "ref":
            return self._memo[node["id"]]
        if kind == "tuple":
            return tuple(self._decode(v) for v in node["v"])
        if kind == "list":
            out: list = self._keep(node, [])
            out.extend(self._decode(v) for v in node["v"])
            return out
        if kind == "dict":
            d: dict = self._keep(node, {})
            keys = [self._decode(k) for k in node["k"]]  # in the encoder's order: keys, then values
            for k, v in zip(keys, node["v"], strict=True):
                d[k] = self._decode(v)
            return d
        if kind == "set":
            return self._keep(node, {self._decode(v) for v in node["v"]})
        if kind == "nd":
            a = np.array(self._arr(node["a"]))
            if node.get("u8") is not None:
                a = _U8_RECIPES[node["u8"]](a)
            return self._keep(node, a)
        if kind == "view":
            base = self._memo[node["of"]]
            if not isinstance(base, np.ndarray):
                raise StateCodecError("a stored view does not refer to an array")
            a = np.ndarray(node["shape"], base.dtype, base, node["offset"], node["strides"])
            return self._keep(node, a)
        if kind == "npgen":
            g = np.random.Generator(np.random.PCG64())
            g.bit_generator.state = node["state"]
            return self._keep(node, g)
        if kind in ("tensor", "tgen", "device"):
            return self._keep(node, self._torch(node))
        if kind in ("pose3", "sim3"):
            return self._keep(node, _gtsam_from(node))
        if kind == "obj":
            return self._object(node)
        raise StateCodecError(f"unknown node kind {kind!r} in the stored state")

    def _keep(self, node: dict, obj: Any) -> Any:
        self._memo[node["id"]] = obj
        return obj

    def _arr(self, name: str) -> np.ndarray:
        if name not in self.arrays:
            raise StateCodecError(f"array {name!r} is missing from the stored arrays")
        return self.arrays[name]

    def _torch(self, node: dict) -> Any:
        import torch

        if node["$"] == "device":
            return torch.device(node["v"])
        if node["$"] == "tgen":
            g = torch.Generator()
            g.set_state(torch.from_numpy(np.array(self._arr(node["a"]), dtype=np.uint8)))
            return self._keep(node, g)
        t = torch.from_numpy(np.array(self._arr(node["a"]))).to(torch.device(node["device"]))
        if node["param"]:
            t = torch.nn.Parameter(t, requires_grad=node["grad"])
        elif node["grad"]:
            t.requires_grad_(True)
        return self._keep(node, t)

    def _object(self, node: dict) -> Any:
        cls = self.classes.get(node["cls"])
        if cls is None:
            raise StateCodecError(f"the stored state names the class {node['cls']!r}, which is not allowed")
        if "hook" in node:
            if cls not in self.hooks:
                raise StateCodecError(f"no decoder for class {node['cls']!r}")
            return self._keep(node, self.hooks[cls](node["hook"], self))
        obj = cls.__new__(cls)
        self._keep(node, obj)
        for k, v in node["state"].items():
            object.__setattr__(obj, k, self._decode(v))
        return obj


# how 8-bit images become float32 in gsslam (the loaders multiply, Frame.from_arrays divides)
_U8_RECIPES = {
    "mul": lambda u: u.astype(np.float32) * np.float32(1.0 / 255.0),
    "div": lambda u: u.astype(np.float32) / np.float32(255.0),
}


def _as_uint8(a: np.ndarray) -> tuple[np.ndarray | None, str | None]:
    """``a`` (float32) as uint8 + the recipe that gives back exactly ``a`` (images from 8-bit files)."""
    if a.dtype != np.float32 or a.size < 4096:
        return None, None
    with np.errstate(invalid="ignore"):
        u = np.rint(a * np.float32(255.0))
    if not (np.isfinite(u).all() and u.min() >= 0 and u.max() <= 255):
        return None, None
    u8 = u.astype(np.uint8)
    for name, recipe in _U8_RECIPES.items():
        if np.array_equal(recipe(u8), a):
            return u8, name
    return None, None


def _torch_module():
    import sys

    return sys.modules.get("torch")  # a run without the map never imported torch: nothing to store


def _gtsam_value(o: Any) -> dict | None:
    import sys

    gtsam = sys.modules.get("gtsam")
    if gtsam is None:
        return None
    if isinstance(o, gtsam.Similarity3):
        return {
            "$": "sim3",
            "R": o.rotation().matrix().ravel().tolist(),
            "t": np.asarray(o.translation()).ravel().tolist(),
            "s": float(o.scale()),
        }
    if isinstance(o, gtsam.Pose3):
        return {
            "$": "pose3",
            "R": o.rotation().matrix().ravel().tolist(),
            "t": np.asarray(o.translation()).ravel().tolist(),
        }
    return None


def _gtsam_from(node: dict) -> Any:
    import gtsam

    R = gtsam.Rot3(np.array(node["R"], dtype=np.float64).reshape(3, 3))
    t = np.array(node["t"], dtype=np.float64)
    if node["$"] == "sim3":
        return gtsam.Similarity3(R, t, float(node["s"]))
    return gtsam.Pose3(R, t)


def dumps(tree: Any) -> str:
    """The JSON text of an encoded tree (NaN and infinities allowed, as Python's json writes them)."""
    return json.dumps(tree, separators=(",", ":"))
