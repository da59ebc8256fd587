"""Name -> component registries.

Every interchangeable component (model, resampler, weighting, noise family, diffusion,
metric, figure) is registered under the name a config uses for it, with a one-line
description that ``pfx list`` prints: the first paragraph of its docstring (write it as one
sentence or phrase), or a description given to ``register``. Adding a component is one new function or class plus
one ``register`` call; nothing else in pfx needs to change.

Components come from pfx itself (built-in) or from plugins (docs/plugins.md). Each entry
remembers its *origin*: None for pfx's own, the plugin's name for a plugin's (set by
:func:`registering_for` while the plugin is imported). A config sees the built-in
components and those of the plugins it names (:meth:`Registry.visible`), never those another
config's plugins registered earlier in the same process. Every registration or removal
bumps a process-wide counter (:func:`changes`), by which the config schema, built from the
registries, knows when to rebuild itself (:func:`pfx.config.schema.config_schema`).
"""

from __future__ import annotations

import difflib
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Annotated, Callable, Collection, Generic, Iterator, Literal, Optional, TypeVar, Union

T = TypeVar("T")

# The plugin being imported (None: pfx's own modules), and the count of registry changes.
_current_origin: Optional[str] = None
_changes = 0


def changes() -> int:
    """How many registrations and removals all registries have seen: a version number of
    their joint contents, for caches built from them."""
    return _changes


def registering_origin() -> Optional[str]:
    """The plugin whose registrations are under way (:func:`registering_for`), None outside one."""
    return _current_origin


@contextmanager
def registering_for(origin: str):
    """Within this block, registrations belong to the plugin ``origin`` (see the module docstring)."""
    global _current_origin
    earlier, _current_origin = _current_origin, origin
    try:
        yield
    finally:
        _current_origin = earlier


class RegistrationClash(ValueError):
    """A name registered twice (a plugin naming its component like a built-in one, say)."""


def first_paragraph(text: str | None) -> str:
    """A docstring's first paragraph on one line, for one-line descriptions: its summary,
    whole even where it wraps onto a second line (the first line alone would stop mid-sentence)."""
    lines = []
    for line in (text or "").strip().splitlines():
        if not line.strip():
            break
        lines.append(line.strip())
    return " ".join(lines)


def closest_name(name: str, candidates) -> str | None:
    """The candidate that looks most like ``name``, or None when nothing is close."""
    matches = difflib.get_close_matches(str(name), [str(c) for c in candidates], n=1, cutoff=0.5)
    return matches[0] if matches else None


# Words that start with a vowel letter but the sound of a consonant ("a ukf": you-kay-eff, "a
# uniform law", "a one-step move"), and the letters whose spoken name starts with a vowel sound
# ("an rts smoother": ar-tee-ess; "a kf": kay-eff), for names spelled out letter by letter;
# Python's "str" is said as a word (string) although it has no vowel.
_VOWEL_LETTER_CONSONANT_SOUND = ("uk", "uni", "usa", "use", "usu", "uti", "eu", "one", "once")
_LETTERS_SPOKEN_WITH_A_VOWEL = "aefhilmnorsx"
_SAID_AS_WORDS = ("str",)


def with_article(phrase: str) -> str:
    """``phrase`` after its indefinite article: "an ekf", "a ukf", "a kf", "an rts smoother",
    "an int", "a list". pfx builds messages from names ("a {kind} filter"); the article goes
    by how the first word sounds. A word without a vowel is read letter by letter (kf, rts,
    mcmc), any other as a word, with the few exceptions above."""
    word = phrase.split(" ", 1)[0].lower()
    if not any(letter in "aeiouy" for letter in word) and word not in _SAID_AS_WORDS:
        vowel_sound = word[:1] in _LETTERS_SPOKEN_WITH_A_VOWEL
    else:
        vowel_sound = word[:1] in "aeiou" and not word.startswith(_VOWEL_LETTER_CONSONANT_SOUND)
    return f"{'an' if vowel_sound else 'a'} {phrase}"


def kind_shorthand(value):
    """Let a config write ``weighting: gaussian`` for ``weighting: {kind: gaussian}``."""
    return {"kind": value} if isinstance(value, str) else value


@dataclass(frozen=True)
class ComponentName:
    """What a :func:`kind_union` chooses ("smoother", "move"), carried in its type's metadata so
    that an unknown kind in a list (``filter.smoothers[0]``) is reported as "unknown smoother
    kind", not by the list index (pfx.config.validation)."""

    what: str


def kind_union(*members, what: str | None = None):
    """The config type of a component chosen by ``kind``: one of ``members`` (pydantic models
    with a ``kind`` literal), written ``{kind: name, ...}`` or, for its defaults, just ``name``;
    ``what`` names the component in messages (a registry's ``what``).

    The JSON Schema (``pfx schema``) says both forms, so editors accept the shorthand too.
    """
    from pydantic import BeforeValidator, Field

    union = Annotated[Union[members], Field(discriminator="kind")]
    names = tuple(member.model_fields["kind"].default for member in members)
    shorthand = BeforeValidator(kind_shorthand, json_schema_input_type=Union[Literal[names], union])
    metadata = (shorthand, ComponentName(what)) if what else (shorthand,)
    return Annotated[(union, *metadata)]


def list_form(minimum: int, maximum: int):
    """For a model that also accepts a list of ``minimum``..``maximum`` numbers (``[v, w]``,
    ``[alpha1, ..., alpha6]``): its JSON Schema, the mapping or that list. Assign it to the
    model's ``__get_pydantic_json_schema__``."""
    def schema(cls, core_schema, handler):
        return {"anyOf": [handler(core_schema), {"type": "array", "items": {"type": "number"},
                                                  "minItems": minimum, "maxItems": maximum}]}
    return classmethod(schema)


class Registry(Generic[T]):
    """An ordered mapping from config names to components, with descriptions."""

    def __init__(self, what: str):
        self.what = what
        self._items: dict[str, T] = {}
        self._descriptions: dict[str, str] = {}
        self._origins: dict[str, Optional[str]] = {}

    def register(self, name: str, description: str | None = None) -> Callable[[T], T]:
        """Decorator: register the decorated object under ``name``."""

        def decorate(item: T) -> T:
            global _changes
            if name in self._items:
                owner = self._origins[name]
                taken = f"a built-in {self.what} of pfx" if owner is None else f"taken by plugin {owner}"
                raise RegistrationClash(f"{self.what} {name!r} is {taken}; choose another name")
            self._items[name] = item
            self._descriptions[name] = description or first_paragraph(getattr(item, "__doc__", ""))
            self._origins[name] = _current_origin
            _changes += 1
            return item

        return decorate

    def add(self, name: str, item: T, description: str | None = None) -> T:
        return self.register(name, description)(item)

    def register_kind(self, component: T) -> T:
        """Class decorator: register a component under the name its ``kind`` declares (the
        default of a pydantic model's ``kind`` field, or a plain class attribute), so that the
        name is written once, at the definition."""
        fields = getattr(component, "model_fields", None)
        name = fields["kind"].default if fields and "kind" in fields else component.kind
        return self.add(name, component)

    def kind_union(self, plugins: Collection[str] = ()):
        """The config type choosing one of the registered components by ``kind`` (see
        :func:`kind_union`): the built-in ones and those of ``plugins``."""
        return kind_union(*self.visible(plugins).values(), what=self.what)

    def visible(self, plugins: Collection[str] = ()) -> dict[str, T]:
        """The components a config naming ``plugins`` may use: pfx's own, then the plugins'
        (in registration order)."""
        return {name: item for name, item in self._items.items()
                if self._origins[name] is None or self._origins[name] in plugins}

    def origin(self, name: str) -> Optional[str]:
        """The plugin that registered ``name`` (None: pfx's own)."""
        return self._origins.get(name)

    def forget(self, origin: str) -> None:
        """Remove what the plugin ``origin`` registered (before importing a changed version of it)."""
        global _changes
        for name in [name for name, owner in self._origins.items() if owner == origin]:
            del self._items[name], self._descriptions[name], self._origins[name]
            _changes += 1

    def __getitem__(self, name: str) -> T:
        try:
            return self._items[name]
        except KeyError:
            raise KeyError(self.unknown_message(name)) from None

    def unknown_message(self, name: str) -> str:
        """'unknown figure 'x' (did you mean 'y'?)': the words for a name not registered."""
        hint = closest_name(name, self._items)
        suffix = f" (did you mean {hint!r}?)" if hint else f" (`pfx list {self.what}s`)"
        return f"unknown {self.what} {name!r}{suffix}"

    def __contains__(self, name: object) -> bool:
        return name in self._items

    def __iter__(self) -> Iterator[str]:
        return iter(self._items)

    def __len__(self) -> int:
        return len(self._items)

    def names(self) -> tuple[str, ...]:
        return tuple(self._items)

    def items(self):
        return self._items.items()

    def describe(self) -> dict[str, str]:
        """name -> one-line description, in registration order."""
        return dict(self._descriptions)
