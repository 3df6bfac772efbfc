"""Light and shadow linking (Object ▸ Shading ▸ Light Linking) → the core's light sets.

Blender's depsgraph (depsgraph_light_linking.cc) turns the emitters' receiver and blocker
collections into what Cycles reads; this is the same computation, from the collections:

- Each distinct receiver collection of an emitter gets a bit (up to 64).
- Each object reached through such collections gets an (include, exclude) pair of collection
  bits: its state in each collection (a child collection's state applies to all objects under
  it). Objects with the same pair share a light set, numbered from 1 (up to 63); the others are
  in the default set 0.
- An emitter lights the sets whose include mask has its collection's bit (all sets when none
  does), less those whose exclude mask has it.

Blockers the same way with the blocker collections (shadow sets and shadow masks).
"""

ALL_SETS = (1 << 64) - 1
MAX_SETS = 64


def _members(collection):
    """(link state, object) for every object of a linking collection: a child collection's
    state for all objects under it, an object's own state for the collection's objects."""
    for child, link in zip(collection.children, collection.collection_children):
        state = link.light_linking.link_state
        for obj in child.all_objects:
            yield state, obj
    for obj, link in zip(collection.objects, collection.collection_objects):
        yield link.light_linking.link_state, obj


def _link_kind(emitters, attr, warn, what):
    """(object name -> set, emitter name -> mask) for the collections in attribute `attr`
    ("receiver_collection" or "blocker_collection") of the emitters."""
    bits = {}  # collection name -> bit
    emitter_bit = {}
    for obj in emitters:
        coll = getattr(obj.light_linking, attr, None)
        if coll is None:
            continue
        if coll.name_full not in bits:
            if len(bits) >= MAX_SETS:
                warn(f"Light linking: more than {MAX_SETS} {what} collections; "
                     f"'{obj.name}' is not linked")
                continue
            bits[coll.name_full] = len(bits)
        emitter_bit[obj.name] = bits[coll.name_full]
    if not bits:
        return {}, {}
    pairs = {}  # object name -> [include, exclude] collection masks
    for obj in emitters:
        if obj.name not in emitter_bit:
            continue
        bit = 1 << emitter_bit[obj.name]
        for state, member in _members(getattr(obj.light_linking, attr)):
            inc, exc = pairs.setdefault(member.name, [0, 0])
            if state == 'INCLUDE':
                pairs[member.name] = [inc | bit, exc & ~bit]
            else:
                pairs[member.name] = [inc & ~bit, exc | bit]
    set_of_pair, sets = {}, {}
    for name, pair in pairs.items():
        key = tuple(pair)
        if key not in set_of_pair:
            if len(set_of_pair) + 1 >= MAX_SETS:
                warn(f"Light linking: more than {MAX_SETS - 1} {what} sets; "
                     f"'{name}' keeps the default set")
                continue
            set_of_pair[key] = len(set_of_pair) + 1
        sets[name] = set_of_pair[key]
    masks = {}
    for name, b in emitter_bit.items():
        included = excluded = 0
        for (inc, exc), s in set_of_pair.items():
            if inc >> b & 1:
                included |= 1 << s
            if exc >> b & 1:
                excluded |= 1 << s
        masks[name] = (included or ALL_SETS) & ~excluded & ALL_SETS
    return sets, masks


def light_links(depsgraph, warn):
    """Object name -> (light_set, light_mask, shadow_set, shadow_mask) for every object that
    light or shadow linking touches (receivers, blockers, emitters); empty without linking."""
    emitters = []
    for obj in depsgraph.objects:
        ll = getattr(obj.original, "light_linking", None)
        if ll is not None and (ll.receiver_collection is not None or ll.blocker_collection is not None):
            emitters.append(obj.original)
    if not emitters:
        return {}
    light_sets, light_masks = _link_kind(emitters, "receiver_collection", warn, "receiver")
    shadow_sets, shadow_masks = _link_kind(emitters, "blocker_collection", warn, "blocker")
    out = {}
    for name in set(light_sets) | set(light_masks) | set(shadow_sets) | set(shadow_masks):
        out[name] = (light_sets.get(name, 0), light_masks.get(name, ALL_SETS),
                     shadow_sets.get(name, 0), shadow_masks.get(name, ALL_SETS))
    return out


def attach_to_lights(lights, links):
    """Sets LightData.links of the lights (LightData) that `links` (light_links()) names."""
    for light in lights:
        if light.name in links:
            _, light_mask, _, shadow_mask = links[light.name]
            if (light_mask, shadow_mask) != (ALL_SETS, ALL_SETS):
                light.links = (light_mask, shadow_mask)
    return lights
