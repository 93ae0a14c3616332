"""The numba engine on its own copies of the state's arrays, as the GPU backend holds them,
with every unsynchronised access an error.

The CPU backends step the state's own NumPy arrays, so a caller that reads or changes the state
without the backend's ``pull`` / ``push`` goes unnoticed on them, and only a GPU run would show
it (one did: docs/performance.md, "Host and device in step"). :class:`SeparateMemory` keeps the
arrays the cupy backend keeps on the device (``cupy_backend.DEVICE_ARRAYS`` and the options'
arrays) as private copies, steps them with the numba kernels, and moves them only on ``pull`` /
``push``, and ``settle`` (the end of ``Simulation.run``) brings back what the kernels changed, as
the cupy backend does. It also catches the access itself:

* a stale read: once a kernel has changed an array, the state's copy is replaced by a
  placeholder that raises :class:`StaleAccess` on any use until that array is pulled;
* an unsynchronised write: a state array changed on the host and not pushed before the next
  kernel call raises :class:`StaleAccess` there;
* a push of a stale array raises too.

The arithmetic is numba's, so a run that synchronises correctly is the plain numba run bit for
bit, at nearly numba's speed. Use: ``monkeypatch.setitem(geodem.backends.BACKENDS, "numba",
SeparateMemory)``.
"""
from __future__ import annotations

import numpy as np

from geodem.backends.cupy_backend import DEVICE_ARRAYS, CupyBackend, stepped_arrays
from geodem.backends.kernels import EXTRA_FORCE
from geodem.backends.numba_backend import NumbaBackend


class StaleAccess(AssertionError):
    """The host touched an array whose device copy is newer (or the other way round)."""


class _Stale:
    """Stands in for a state array the kernels changed since the host last pulled it (its
    shape and dtype stay readable: they do not go stale)."""

    __slots__ = ("_name", "shape", "dtype", "ndim", "size")

    def __init__(self, name, like):
        object.__setattr__(self, "_name", name)
        for k in ("shape", "dtype", "ndim", "size"):
            object.__setattr__(self, k, getattr(like, k))

    def _fail(self, *args, **kwargs):
        name = object.__getattribute__(self, "_name")
        raise StaleAccess(f"state.{name} was read or written on the host after the kernels "
                          f"changed it, without backend.pull({name!r},) or sim.sync()")

    def __getattr__(self, name):
        self._fail()

    def __setattr__(self, name, value):
        self._fail()

    def __len__(self):
        return self.shape[0]


for _m in ("__getitem__", "__setitem__", "__array__", "__iter__", "__contains__",
           "__add__", "__sub__", "__mul__", "__truediv__", "__radd__", "__rsub__", "__rmul__",
           "__rtruediv__", "__iadd__", "__isub__", "__imul__", "__neg__", "__abs__", "__pow__",
           "__lt__", "__gt__", "__le__", "__ge__", "__eq__", "__ne__", "__bool__", "__float__",
           "__int__", "__array_function__", "__array_ufunc__", "__copy__", "__deepcopy__"):
    setattr(_Stale, _m, _Stale._fail)


class _DeviceView:
    """The state as the kernels see it: the device copies for the device arrays, the state
    itself for everything else (scalars, groups); properties and methods of the state see the
    device copies too."""

    def __init__(self, real, dev):
        object.__setattr__(self, "_real", real)
        object.__setattr__(self, "_dev", dev)

    def __getattr__(self, name):
        dev = object.__getattribute__(self, "_dev")
        if name in dev:
            return dev[name]
        real = object.__getattribute__(self, "_real")
        attr = getattr(type(real), name, None)
        if isinstance(attr, property) or callable(attr) and hasattr(attr, "__get__"):
            return attr.__get__(self)
        return getattr(real, name)

    def __setattr__(self, name, value):
        dev = object.__getattribute__(self, "_dev")
        if name in dev:
            dev[name] = value
        else:
            setattr(object.__getattribute__(self, "_real"), name, value)


class SeparateMemory(NumbaBackend):
    """:class:`NumbaBackend` whose arrays live apart from the state (see the module doc)."""

    def attach(self, state):
        self.real = state
        self.dev = {}
        self.hidden = {}  # name -> the state's own array, replaced by a _Stale meanwhile
        self.synced = {}  # name -> the host's copy at its last pull or push
        self._copy_in(None)
        super().attach(_DeviceView(state, self.dev))

    def _names(self):
        s = self.real
        return DEVICE_ARRAYS + tuple(k for k in EXTRA_FORCE
                                     if k in self.hidden or getattr(s, k) is not None)

    def _copy_in(self, names):
        for k in self._names() if names is None else names:
            if k in self.hidden:
                raise StaleAccess(f"push of state.{k}, whose device copy the kernels changed "
                                  f"since the host last pulled it")
            self.dev[k] = np.array(getattr(self.real, k), copy=True)
            self.synced[k] = self.dev[k].copy()

    def pull(self, names=None):
        super().pull(names)  # the partners' springs first (on the copies)
        for k in self._names() if names is None else names:
            if k in self.hidden:
                setattr(self.real, k, self.hidden.pop(k))
            getattr(self.real, k)[...] = self.dev[k]
            self.synced[k] = self.dev[k].copy()

    def push(self, names=None):
        self._copy_in(names)
        super().push(names)

    settle = CupyBackend.settle  # the end of a run as on the GPU: what the kernels changed

    def _kernel(self, run):
        for k, old in self.synced.items():
            if k in self.hidden:
                continue
            cur = getattr(self.real, k)
            if cur is not None and (cur.shape != old.shape or
                                    not np.array_equal(cur, old, equal_nan=True)):
                raise StaleAccess(f"state.{k} was changed on the host and not pushed before "
                                  f"the next step (backend.push(({k!r},)))")
        before = {k: self.dev[k].copy() for k in stepped_arrays(self.real) if k in self.dev}
        out = run()
        for k, old in before.items():
            if k not in self.hidden and not np.array_equal(self.dev[k], old, equal_nan=True):
                self.hidden[k] = getattr(self.real, k)
                setattr(self.real, k, _Stale(k, self.hidden[k]))
        return out

    def move(self, dt):
        return self._kernel(lambda: super(SeparateMemory, self).move(dt))

    def force(self, dt, code_t, code_s):
        return self._kernel(lambda: super(SeparateMemory, self).force(dt, code_t, code_s))

    def steps(self, dt, nsteps, step0):
        return self._kernel(lambda: super(SeparateMemory, self).steps(dt, nsteps, step0))

    def elastic_energy(self):
        return super().elastic_energy().copy()  # the host gets a copy, as from the device
