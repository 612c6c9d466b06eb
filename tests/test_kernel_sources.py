"""Rules every kernel source follows, checked on the text of every kernel folder.

The one rule so far: every function that takes or returns a 3-component vector (float3,
int3, ...) by value is declared ``PRT_INLINE`` (kernels/inline.h: such a call left out of
line is miscompiled by Intel's CPU runtime; the rule keeps every kernel clear of it
whatever the compiler decides).
"""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from helpers import PROJECT, TESTS

KERNEL_FOLDERS = (PROJECT / "kernels", TESTS / "toy_method" / "kernels")


def function_heads(source: str) -> list[str]:
    """The text before the opening brace of every function defined at file scope
    (comments, preprocessor lines and their continuations left out), whitespace folded."""
    text = re.sub(r"/\*.*?\*/", " ", source, flags=re.S)
    text = re.sub(r"//[^\n]*", " ", text)
    text = re.sub(r"(?m)^[ \t]*#(?:[^\n]*\\\n)*[^\n]*", " ", text)
    heads, depth, start = [], 0, 0
    for i, ch in enumerate(text):
        if ch == "{":
            head = " ".join(text[start:i].split())
            if depth == 0 and "(" in head and "=" not in head.split("(")[0] \
                    and not head.startswith(("struct", "typedef", "union", "enum")):
                heads.append(head)
            depth += 1
        elif ch == "}":
            depth -= 1
            start = i + 1 if depth == 0 else start
        elif ch == ";" and depth == 0:
            start = i + 1
    return heads


# a 3-component vector type by value (not a pointer to one)
VECTOR3 = re.compile(r"\b(?:float|double|half|u?char|u?short|u?int|u?long)3\b(?!\s*\*)")


def helper_heads_not_inlined(source: str) -> list[str]:
    """Heads of functions, not kernels, that take or return a 3-component vector by value
    and are not declared ``PRT_INLINE``."""
    return [h for h in function_heads(source)
            if not re.search(r"\b(__kernel|kernel)\b", h) and VECTOR3.search(h)
            and not h.startswith("PRT_INLINE ")]


def kernel_files() -> list[Path]:
    return sorted(p for folder in KERNEL_FOLDERS for p in folder.rglob("*.[ch]*"))


def test_the_parser_finds_helpers_kernels_and_skips_macros_and_comments():
    source = """
    #define ARGS \\
        __global float* a, { not code }
    /* inline float3 commented(float x) { } */
    PRT_INLINE float3 ok(float x) { if (x) { return (float3)(x); } return 0; }
    inline float3 bare(float3 v) { return v; }
    __attribute__((noinline)) float also_bare(uint3 x) { return x.x; }
    inline void by_pointer(float3* v, int n) { }
    inline float scalar(float x) { return x; }
    typedef struct { float a; } pair;
    __kernel void k(__global float* out) { out[0] = ok(1.0f).x; }
    """
    def name(head: str) -> str:  # the identifier before the parameter list
        return re.search(r"(\w+)\s*\([^()]*\)$", head).group(1)

    assert [name(h) for h in function_heads(source)] == [
        "ok", "bare", "also_bare", "by_pointer", "scalar", "k"]
    assert [name(h) for h in helper_heads_not_inlined(source)] == ["bare", "also_bare"]


@pytest.mark.parametrize("path", kernel_files(), ids=lambda p: p.name)
def test_every_function_passing_a_vector3_is_force_inlined(path):
    assert helper_heads_not_inlined(path.read_text()) == []


def test_every_kernel_folder_is_checked():
    assert {p.name for p in kernel_files()} >= {"brdf.h", "lights.h", "d2i.cl", "toy_shade.cl"}
