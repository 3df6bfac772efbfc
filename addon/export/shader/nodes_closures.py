"""Shader nodes → weighted closures: Mix / Add Shader, the BSDFs, Emission, Holdout,
Subsurface, Principled BSDF, Principled Hair, the Hair BSDF and the Ray Portal BSDF (a
ShaderCompiler mixin)."""

from .graph import _Cycle
from .values import GREY, ONE, ZERO, const_color, const_float


class ClosureNodes:
    """Translators of the shader (closure) nodes (ShaderCompiler mixin)."""

    def closure(self, kind, weight, **params):
        if self.is_zero(weight):
            return
        regs = {k: self.reg(v) for k, v in params.items() if v is not None}
        if weight is not None and weight.is_const and all(x == 1.0 for x in weight.const[:3]):
            weight = None
        w = None if weight is None else self.reg(self.as_color(weight))
        self.ops.append(("closure", kind, w, regs))

    def shader_input(self, socket, ctx, weight):
        """Emits the closures of what feeds shader input `socket`, scaled by weight."""
        if self.is_zero(weight):
            return
        src = self.source(socket, ctx)
        if src is None or src[0] == "default":
            return  # nothing connected: no closure (Cycles renders black)
        _, node, out, nctx = src
        if out.type != 'SHADER':  # Cycles turns a value linked into a shader into emission
            v = self.node_output(node, out, nctx, socket, "color")
            self.closure("emission", weight, color=self.as_color(v) if v is not None else ONE)
            return
        key = (node.as_pointer(), out.identifier, self.ctx_key(nctx))
        if key in self.visiting:
            raise _Cycle(node.name)
        self.visiting.add(key)
        try:
            self.shader_node(node, nctx, weight)
        finally:
            self.visiting.discard(key)

    def normal(self, node, ctx, name="Normal"):
        socket = node.inputs.get(name)
        return None if socket is None else self.value(socket, ctx, "vector")

    def shader_node(self, node, ctx, weight):
        t = node.type
        inp = lambda name, kind: self.input(node, name, ctx, kind)  # noqa: E731
        if getattr(self, "background", False) and t not in ('MIX_SHADER', 'ADD_SHADER', 'EMISSION'):
            if t == 'BACKGROUND':  # the world's light: Color times Strength (as Emission)
                color = self.scale(inp("Color", "color"), inp("Strength", "float"))
                self.closure("emission", weight, color=self.as_color(color))
            else:  # Cycles' background shader keeps only its emission
                self.problem(f"'{node.name}' ({node.bl_idname}) is not a world shader (black, as Cycles)")
            return
        if t == 'MIX_SHADER':
            fac = self.math("ADD", inp("Fac", "float"), ZERO, clamp=True)
            w2 = self.scale(weight, fac)
            w1 = self.scale(weight, self.math("SUBTRACT", ONE, fac))
            self.shader_input(node.inputs[1], ctx, w1)
            self.shader_input(node.inputs[2], ctx, w2)
        elif t == 'ADD_SHADER':
            self.shader_input(node.inputs[0], ctx, weight)
            self.shader_input(node.inputs[1], ctx, weight)
        elif t == 'BSDF_DIFFUSE':
            # A Roughness that is not a constant zero: Cycles' Oren-Nayar in the core.
            r = inp("Roughness", "float")
            rough = {} if r.is_const and r.const[0] == 0.0 else {"roughness": r}
            self.closure("diffuse", weight, color=inp("Color", "color"),
                         normal=self.normal(node, ctx), **rough)
        elif t == 'BSDF_TOON':
            glossy = {"glossy": ONE} if node.component == 'GLOSSY' else {}
            self.closure("toon", weight, color=inp("Color", "color"), size=inp("Size", "float"),
                         smooth=inp("Smooth", "float"), normal=self.normal(node, ctx), **glossy)
        elif t == 'BSDF_SHEEN':
            # Microfibre (Zeltner et al., Cycles' default) or Ashikhmin velvet.
            velvet = {"velvet": ONE} if getattr(node, "distribution", 'MICROFIBER') == 'ASHIKHMIN' else {}
            self.closure("sheen", weight, color=inp("Color", "color"),
                         roughness=inp("Roughness", "float"), normal=self.normal(node, ctx), **velvet)
        elif t == 'BSDF_GLOSSY':
            rough = inp("Roughness", "float")
            self.closure("glossy", weight, color=inp("Color", "color"), roughness=rough,
                         normal=self.normal(node, ctx),
                         multiscatter=self._multiscatter(node, rough),
                         **self._distribution(node, rough),
                         **self._anisotropy(node, ctx, "Anisotropy", "Rotation"))
        elif t in ('BSDF_GLASS', 'BSDF_REFRACTION'):
            rough = inp("Roughness", "float")
            self.closure("glass" if t == 'BSDF_GLASS' else "refraction", weight,
                         color=inp("Color", "color"), roughness=rough, ior=inp("IOR", "float"),
                         normal=self.normal(node, ctx),
                         multiscatter=self._multiscatter(node, rough) if t == 'BSDF_GLASS' else None,
                         **self._distribution(node, rough))
        elif t == 'BSDF_METALLIC':
            rough = inp("Roughness", "float")
            physical = node.fresnel_type == 'PHYSICAL_CONDUCTOR'
            params = dict(ior=inp("IOR", "vector"), extinction=inp("Extinction", "vector"),
                          physical=ONE) if physical else dict(
                base_color=inp("Base Color", "color"), edge_tint=inp("Edge Tint", "color"))
            self.closure("metallic", weight, roughness=rough, normal=self.normal(node, ctx),
                         multiscatter=self._multiscatter(node, rough), **params,
                         **self._distribution(node, rough),
                         **self._anisotropy(node, ctx, "Anisotropy", "Rotation"))
        elif t == 'BSDF_TRANSLUCENT':
            self.closure("translucent", weight, color=inp("Color", "color"),
                         normal=self.normal(node, ctx))
        elif t == 'BSDF_TRANSPARENT':
            self.closure("transparent", weight, color=inp("Color", "color"))
        elif t == 'BSDF_RAY_PORTAL':
            # Cycles' Ray Portal BSDF: the path goes on from Position along Direction; both
            # hide their values, so unlinked they are Cycles' defaults (the shading point, the
            # incoming direction), which the core takes where the key is absent.
            linked = lambda name: (inp(name, "vector") if self.source(node.inputs[name], ctx) is not None  # noqa: E731
                                   else None)
            self.closure("ray_portal", weight, color=inp("Color", "color"),
                         position=linked("Position"), direction=linked("Direction"))
        elif t == 'BSDF_HAIR_PRINCIPLED':
            self.principled_hair(node, inp, weight)
        elif t == 'BSDF_HAIR':
            # Cycles' Hair BSDF, one component; its Tangent only where linked (else the strand's
            # direction, or on a mesh the triangle's dPdv).
            tangent = node.inputs["Tangent"]
            kind = "hair_transmission" if node.component == 'Transmission' else "hair_reflection"
            self.closure(kind, weight, color=inp("Color", "color"), offset=inp("Offset", "float"),
                         roughness_u=inp("RoughnessU", "float"), roughness_v=inp("RoughnessV", "float"),
                         tangent=inp("Tangent", "vector") if tangent.is_linked else None)
        elif t == 'EMISSION':
            color = self.scale(inp("Color", "color"), inp("Strength", "float"))
            self.closure("emission", weight, color=self.as_color(color))
        elif t == 'BSDF_PRINCIPLED':
            self.principled(node, ctx, weight)
        elif t == 'HOLDOUT':
            self.closure("holdout", weight)
        elif t == 'SUBSURFACE_SCATTERING':
            # Inputs the method hides (Roughness but for Random Walk, IOR for Burley) are not
            # found by name: the core's defaults stand in, unused.
            opt = lambda name, kind: inp(name, kind) if node.inputs.get(name) is not None else None  # noqa: E731
            self.closure("subsurface", weight, color=inp("Color", "color"), scale=inp("Scale", "float"),
                         radius=inp("Radius", "vector"), ior=opt("IOR", "float"),
                         roughness=opt("Roughness", "float"), anisotropy=opt("Anisotropy", "float"),
                         normal=self.normal(node, ctx), method=self._subsurface_method(node, node.falloff))
        elif node.bl_idname == 'ShaderNodeEeveeSpecular':
            # EEVEE only: Cycles renders it black (no closure), and so does Pathlight.
            self.problem(f"'{node.name}' ({node.bl_idname}) is EEVEE only (black, as in Cycles)")
        else:
            self._fallback_shader(node, ctx, weight)

    # The core's flag key for each of Blender's distributions besides GGX (Multiscatter GGX is
    # GGX with the multiscatter key); the core refuses Ashikhmin-Shirley but on Glossy, and
    # Blender offers it nowhere else.
    _DISTRIBUTION_KEYS = {'BECKMANN': "beckmann", 'ASHIKHMIN_SHIRLEY': "ashikhmin_shirley"}

    def _distribution(self, node, roughness):
        """The closure's distribution flag (a register of 1): none for GGX and Multiscatter
        GGX, and none for a constant zero roughness (every distribution is the same mirror)."""
        dist = node.distribution
        if dist in ('GGX', 'MULTI_GGX') or (roughness.is_const and roughness.const[0] == 0.0):
            return {}
        key = self._DISTRIBUTION_KEYS.get(dist)
        if key is None or (key == "ashikhmin_shirley" and node.type != 'BSDF_GLOSSY'):
            self.problem(f"'{node.name}': {dist.replace('_', ' ').title()} distribution is "
                         "approximated by GGX")
            return {}
        return {key: ONE}

    @staticmethod
    def _multiscatter(node, roughness):
        """ONE (a flag register) for Multiscatter GGX, which the core's energy compensation
        follows; None for single-scatter GGX and for a constant zero roughness (a mirror)."""
        if node.distribution != 'MULTI_GGX':
            return None
        if roughness.is_const and roughness.const[0] == 0.0:
            return None
        return ONE

    def _anisotropy(self, node, ctx, amount, rotation):
        """The closure keys of a Glossy/Metallic node's anisotropy (none where it is a constant
        zero): the amount, the rotation and the tangent (unlinked: Cycles' default)."""
        aniso = self.input(node, amount, ctx, "float")
        if aniso.is_const and aniso.const[0] == 0.0:
            return {}
        return dict(anisotropy=aniso, rotation=self.input(node, rotation, ctx, "float"),
                    tangent=self.principled_tangent(node, ctx, "Tangent"))

    def _fallback_shader(self, node, ctx, weight):
        """An unsupported shader node: a diffuse closure of its Color input if it has one,
        else grey diffuse."""
        color = node.inputs.get("Color")
        if color is not None and color.type == 'RGBA':
            self.problem(f"'{node.name}' ({node.bl_idname}) is not supported (diffuse of its "
                         "Color)")
            c = self.value(color, ctx, "color")
        else:
            self.problem(f"'{node.name}' ({node.bl_idname}) is not supported (grey diffuse)")
            c = const_color(GREY)
        self.closure("diffuse", weight, color=c)

    # -------------------------------------------------- hair

    def principled_hair(self, node, inp, weight):
        """The Principled Hair BSDF: Cycles' Chiang model (core: HairChiangBsdf) or Huang's
        (HairHuangBsdf: Aspect Ratio and the lobe weights instead of Radial Roughness and
        Coat)."""
        huang = node.model == 'HUANG'
        # Each model hides the other's own inputs (bpy then cannot find them by name): their
        # Blender defaults stand in.
        hidden = {"Radial Roughness": 0.3, "Coat": 0.0, "Aspect Ratio": 0.85, "Reflection": 1.0,
                  "Transmission": 1.0, "Secondary Reflection": 1.0}
        own = lambda name: (inp(name, "float") if node.inputs.get(name) is not None  # noqa: E731
                            else const_float(hidden[name]))
        mode = {'ABSORPTION': "absorption", 'MELANIN': "melanin"}.get(node.parametrization, "color")
        params = dict(roughness=inp("Roughness", "float"), ior=inp("IOR", "float"),
                      offset=inp("Offset", "float"), random_roughness=inp("Random Roughness", "float"))
        if huang:
            params.update(aspect_ratio=own("Aspect Ratio"), r=own("Reflection"), tt=own("Transmission"),
                          trt=own("Secondary Reflection"))
        else:
            params.update(radial_roughness=own("Radial Roughness"), coat=own("Coat"))
        if mode == "absorption":
            params["absorption"] = inp("Absorption Coefficient", "vector")
        elif mode == "melanin":
            params.update(melanin=inp("Melanin", "float"), melanin_redness=inp("Melanin Redness", "float"),
                          tint=inp("Tint", "color"), random_color=inp("Random Color", "float"))
        else:
            params["color"] = inp("Color", "color")
        if node.inputs["Random"].is_linked:
            params["random"] = inp("Random", "float")
        elif any(v is not None and not (v.is_const and v.const[0] == 0.0)
                 for v in (params.get("random_roughness"), params.get("random_color"))):
            # Unlinked: Cycles reads the strand's own random number (Curves Info's Random).
            params["random"] = self.emit("float", "curves_info", "RANDOM")
        self.closure(("principled_hair_huang_" if huang else "principled_hair_") + mode, weight, **params)

    # -------------------------------------------------- Principled BSDF

    def principled(self, node, ctx, weight):
        inp = lambda name, kind: self.input(node, name, ctx, kind)  # noqa: E731
        extra = self._principled_extra(node, ctx)
        alpha = self.math("ADD", inp("Alpha", "float"), ZERO, clamp=True)
        opaque = self.scale(weight, alpha)
        if not (alpha.is_const and alpha.const[0] == 1.0):
            self.closure("transparent", self.scale(weight, self.math("SUBTRACT", ONE, alpha)),
                         color=const_color((1, 1, 1, 1)))
        rough = inp("Roughness", "float")
        coat = {}
        coat_weight = inp("Coat Weight", "float")
        if not (coat_weight.is_const and coat_weight.const[0] <= 0.0):
            coat = dict(coat_weight=coat_weight, coat_roughness=inp("Coat Roughness", "float"),
                        coat_ior=inp("Coat IOR", "float"), coat_tint=inp("Coat Tint", "color"),
                        coat_normal=self.normal(node, ctx, "Coat Normal"))
        # Emission: under a sheen or coat the core dims it by them (Cycles adds it after both
        # layers); else a plain Emission closure of the same weight.
        strength = inp("Emission Strength", "float")
        emission = None
        if not (strength.is_const and strength.const[0] == 0.0):
            emission = self.as_color(self.scale(inp("Emission Color", "color"), strength))
            if coat or "sheen_weight" in extra:
                extra["emission"], emission = emission, None
        self.closure("principled", opaque,
                     base_color=inp("Base Color", "color"),
                     metallic=inp("Metallic", "float"),
                     roughness=rough,
                     ior=inp("IOR", "float"),
                     transmission=inp("Transmission Weight", "float"),
                     specular_level=inp("Specular IOR Level", "float"),
                     specular_tint=inp("Specular Tint", "color"),
                     normal=self.normal(node, ctx),
                     multiscatter=self._multiscatter(node, rough),
                     **coat, **extra)
        if emission is not None:
            self.closure("emission", opaque, color=emission)

    # The Principled BSDF's feature groups beyond the base, coat and emission: (the group,
    # its switch input (left out where it is a constant zero), and its operands (the closure's
    # key, the socket, its kind)). The core reads them from a PrincipledExtra op.
    _PRINCIPLED_GROUPS = (
        ("anisotropy", "Anisotropic", (("anisotropic", "Anisotropic", "float"),
                                       ("anisotropic_rotation", "Anisotropic Rotation", "float"),
                                       ("tangent", "Tangent", "tangent"))),
        ("thin film", "Thin Film Thickness", (("thin_film_thickness", "Thin Film Thickness", "float"),
                                              ("thin_film_ior", "Thin Film IOR", "float"))),
        ("sheen", "Sheen Weight", (("sheen_weight", "Sheen Weight", "float"),
                                   ("sheen_roughness", "Sheen Roughness", "float"),
                                   ("sheen_tint", "Sheen Tint", "color"))),
        ("diffuse roughness", "Diffuse Roughness", (("diffuse_roughness", "Diffuse Roughness", "float"),)),
        ("subsurface", "Subsurface Weight", (("subsurface_weight", "Subsurface Weight", "float"),
                                             ("subsurface_radius", "Subsurface Radius", "vector"),
                                             ("subsurface_scale", "Subsurface Scale", "float"),
                                             ("subsurface_ior", "Subsurface IOR", "float"),
                                             ("subsurface_anisotropy", "Subsurface Anisotropy", "float"))),
    )

    # Groups that the core does not render yet: warned about and left out.
    _PRINCIPLED_UNSUPPORTED = {
    }

    def _principled_extra(self, node, ctx):
        """The closure keys of the Principled feature groups in use (switch input not a
        constant zero); an unsupported one in use is warned about instead."""
        extra, ignored = {}, []
        for group, switch, operands in self._PRINCIPLED_GROUPS:
            socket = node.inputs.get(switch)
            if socket is None:
                continue
            v = self.value(socket, ctx, "float")
            if v.is_const and v.const[0] == 0.0:
                continue
            if group in self._PRINCIPLED_UNSUPPORTED:
                ignored.append(group)
                continue
            for key, name, kind in operands:
                if kind == "tangent":
                    extra[key] = self.principled_tangent(node, ctx, name)
                elif node.inputs.get(name) is not None:
                    extra[key] = self.input(node, name, ctx, kind)
        if ignored:
            self.problem(f"'{node.name}': {', '.join(ignored)} not supported (ignored)")
        if "subsurface_weight" in extra:
            extra["subsurface_method"] = self._subsurface_method(node, node.subsurface_method)
        return extra

    # The core's numbers for Blender's subsurface methods (core/scene/shader.h SubsurfaceMethod).
    _SUBSURFACE_METHODS = {'BURLEY': 0.0, 'RANDOM_WALK': 1.0, 'RANDOM_WALK_SKIN': 2.0}

    def _subsurface_method(self, node, method):
        """A constant register of the method (Burley: Cycles' disk sampling; Random Walk; Skin)."""
        return const_float(self._SUBSURFACE_METHODS.get(method, 1.0))

    def principled_tangent(self, node, ctx, name):
        """The Tangent input; unlinked, Cycles' default for a mesh: the Geometry node's
        Tangent, radial around the object's Z axis from the generated coordinates."""
        socket = node.inputs.get(name)
        if socket is None or not socket.is_linked:
            return self.emit("vector", "tangent", "Z", 0)
        return self.input(node, name, ctx, "vector")
