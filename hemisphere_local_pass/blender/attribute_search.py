"""The radiosity attribute's search list: the colour attributes the scene's meshes actually have."""

from __future__ import annotations

__all__ = ["COLOUR_TYPES", "colour_attributes"]

#: Attribute types the scene export reads as radiance (``scene_export._VALUE_PROP``).
COLOUR_TYPES = ("FLOAT_COLOR", "BYTE_COLOR", "FLOAT_VECTOR")


def colour_attributes(scene, edit_text: str = "") -> list:
    """``[(name, "Mesh A, Mesh B (FACE)"), ...]`` of the colour/vector attributes on the scene's mesh
    objects (every mesh when ``scene`` is None), sorted by name, filtered by ``edit_text``
    (case-insensitive substring)."""
    import bpy

    found: dict = {}
    objects = scene.objects if scene is not None else bpy.data.objects
    seen = set()
    for ob in objects:
        mesh = ob.data if ob.type == 'MESH' else None
        if mesh is None or mesh.name in seen:
            continue
        seen.add(mesh.name)
        for attr in mesh.attributes:
            if attr.data_type in COLOUR_TYPES and not attr.name.startswith("."):
                found.setdefault(attr.name, []).append(f"{ob.name} ({attr.domain.title()})")
    needle = (edit_text or "").lower()
    out = []
    for name in sorted(found):
        if needle and needle not in name.lower():
            continue
        users = found[name]
        desc = ", ".join(users[:3]) + (f" and {len(users) - 3} more" if len(users) > 3 else "")
        out.append((name, desc))
    return out
