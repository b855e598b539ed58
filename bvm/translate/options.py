"""What a VM asks of the translator: the optimizations to apply and the cache to use."""

from __future__ import annotations

from dataclasses import dataclass, field

from bvm.translate.cache import SHARED_CACHE, CodeCache


@dataclass(frozen=True)
class TranslateOptions:
    """Translator settings of one VM; the defaults are what every host runs.

    Turning an optimization off exists to compare against it (the tests check that
    budgets, errors and recursion depth are the same either way).
    """

    #: A call of the running closure enters its unguarded body directly (see selfcall).
    self_calls: bool = True
    #: Outer loops count iterations by a `for` over one budget chunk (see codegen).
    chunked_loops: bool = True
    #: VMs of one program reuse each other's translations (see shared.py).
    share_translations: bool = True
    #: Where compiled translations are kept; VMs sharing one share compiled code.
    cache: CodeCache = field(default=SHARED_CACHE, compare=False)


DEFAULT_OPTIONS = TranslateOptions()
