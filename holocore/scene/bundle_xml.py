"""The XML of a scene bundle, read as Mitsuba reads it, for the bundle check (:mod:`holocore.scene.bundle`):
parsing with defusedxml under the bundle's caps (bytes, nesting, UTF-8 only), and the ``<default>`` parameters'
substitution in one pass. Pure Python: no Mitsuba import."""

from __future__ import annotations

import re
from pathlib import Path
from typing import TYPE_CHECKING

from holocore.scene.errors import BundleError

if TYPE_CHECKING:
    from holocore.scene.bundle import BundleLimits

__all__ = ["parse_xml", "one_line", "Params", "NAME"]

NAME = re.compile(r"^[A-Za-z_][A-Za-z0-9_.-]{0,63}$")  # a <default> parameter's name
XML_DECLARATION = re.compile(rb"^(?:\xef\xbb\xbf)?\s*<\?xml\s")
XML_ENCODING = re.compile(rb"\bencoding\s*=\s*([\"'])(.*?)\1", re.DOTALL)


def parse_xml(path: Path, limits: BundleLimits, name: str):
    """The root element of an XML file, parsed with defusedxml; nesting deeper than ``limits.max_xml_depth``
    is refused while parsing (no deep tree is ever built). Every failure is a BundleError on one line."""
    from xml.etree.ElementTree import ParseError, TreeBuilder

    from defusedxml import DefusedXmlException
    from defusedxml.ElementTree import XMLParser

    if path.stat().st_size > limits.max_xml_bytes:
        raise BundleError(f"{name}: XML larger than {limits.max_xml_bytes} bytes")
    raw = path.read_bytes()
    # the whole declaration, however long (padding pushed an encoding past a fixed window, where expat and
    # Mitsuba's parser still read it)
    m = XML_ENCODING.search(raw, 0, raw.find(b"?>")) if XML_DECLARATION.match(raw) else None
    if m is not None and m.group(2).strip().lower() not in (b"utf-8", b"utf8"):
        # Mitsuba's parser reads anything but Latin-1 as UTF-8: any other declared encoding would make the two
        # parsers see different attribute values
        raise BundleError(f"{name}: XML declares encoding {m.group(2)[:40].decode('ascii', 'replace')!r}; scene "
                          "files must be UTF-8")

    class DepthCapped(TreeBuilder):
        depth = 0

        def start(self, tag, attrs):
            self.depth += 1
            if self.depth > limits.max_xml_depth:
                raise BundleError(f"{name}: XML elements nested deeper than {limits.max_xml_depth}")
            return super().start(tag, attrs)

        def end(self, tag):
            self.depth -= 1
            return super().end(tag)

    try:
        # fed in one piece: expat rescans a token split over chunks, quadratic in a huge attribute
        parser = XMLParser(target=DepthCapped(), encoding="utf-8", forbid_dtd=True, forbid_entities=True,
                           forbid_external=True)
        parser.feed(raw)
        root = parser.close()
    except BundleError:
        raise
    except DefusedXmlException as exc:
        raise BundleError(f"{name}: refused XML construct ({type(exc).__name__}): DTDs, entities and external "
                          "references are not allowed") from None
    except (ParseError, UnicodeError, ValueError, LookupError) as exc:
        raise BundleError(f"{name}: not well-formed XML: {one_line(exc)}") from None
    except Exception as exc:  # noqa: BLE001 - whatever else the parser raises, the user gets one line
        raise BundleError(f"{name}: XML could not be parsed ({type(exc).__name__}: {one_line(exc)})") from None
    if root is None:
        raise BundleError(f"{name}: XML holds no element")
    return root


def one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text[:200]


class Params:
    """Mitsuba's ``<default>`` namespace: ordered, global over includes.

    Mitsuba substitutes an attribute by replacing every ``$name`` of every parameter in turn, longest name
    first (ties in no set order). Values hold no ``$``, so at each ``$`` that is the longest parameter name
    starting there, unless a replacement made later in that order completes a longer name across the next
    ``$`` (``$a$bc`` with parameters ``a``, ``aX`` and ``bc`` = ``X``): such an attribute is refused, and all
    others are substituted in one pass, at most 64 dictionary lookups per ``$``."""

    _LONGEST = 64  # NAME's longest name

    def __init__(self, limits: BundleLimits) -> None:
        self.limits = limits
        self.values: dict[str, str] = {}
        self._stems: set[str] = set()  # proper prefixes of the names ("" once there is one)

    def define(self, name: str, value: str, where: str) -> None:
        if not NAME.match(name):
            raise BundleError(f"{where}: <default name={name[:40]!r}>: parameter names are letters, digits, '_', "
                              "'.' and '-', starting with a letter or '_'")
        if name in self.values:
            raise BundleError(f"{where}: <default name={name!r}> is defined twice; define each parameter once")
        if "$" in value:
            raise BundleError(f"{where}: <default name={name!r}> has a value holding '$'; values are not expanded")
        if len(self.values) >= self.limits.max_defaults:
            raise BundleError(f"{where}: more than {self.limits.max_defaults} <default> parameters")
        self.values[name] = value
        self._stems.update(name[:i] for i in range(len(name)))

    def substitute(self, value: str, where: str, budget: int) -> str:
        """``value`` as Mitsuba substitutes it; BundleError for an undefined or ambiguous ``$parameter``, or
        when the result would be longer than ``budget`` characters."""
        if "$" not in value:
            return value
        pieces = value.split("$")
        out = [pieces[0]]
        size = len(pieces[0])
        last = len(pieces) - 1
        memo: dict[str, tuple[str, bool]] = {}  # segment -> (its replacement, could it join the next one)
        for i in range(1, last + 1):
            seg = pieces[i]
            done = memo.get(seg)
            if done is None:
                done = memo[seg] = (self._replace(seg, value, where), seg in self._stems)
            if done[1] and i < last:
                raise BundleError(f"{where}: {value[:80]!r}: '${seg[:40]}' followed by another $parameter could "
                                  "join it into a longer parameter name; separate them")
            out.append(done[0])
            size += len(done[0])
            if size > budget:
                raise BundleError(f"{where}: $parameters expand the scene's XML past "
                                  f"{self.limits.max_xml_total_bytes} bytes")
        return "".join(out)

    def _replace(self, seg: str, value: str, where: str) -> str:
        """The text after one ``$``: the longest parameter name it starts with, replaced."""
        for n in range(min(len(seg), self._LONGEST), 0, -1):
            if seg[:n] in self.values:
                return self.values[seg[:n]] + seg[n:]
        raise BundleError(f"{where}: {value[:80]!r} uses an undefined $parameter")
