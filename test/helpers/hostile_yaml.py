"""Hostile YAML shared by the input tests (scenes, parameters files, bag metadata)."""

# A "billion laughs": nine x's, then eight lists each of nine aliases of the one before — 9⁹
# (about 3.9e8) nodes once expanded, from about 400 bytes.
ALIAS_BOMB = "a: &a [x,x,x,x,x,x,x,x,x]\n" + "".join(
    f"{b}: &{b} [" + ",".join([f"*{a}"] * 9) + "]\n"
    for a, b in zip("abcdefgh", "bcdefghi", strict=True))
