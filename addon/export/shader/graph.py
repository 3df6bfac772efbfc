"""Following the links of a node tree to what feeds an input, through reroutes, muted nodes
and node groups (a ShaderCompiler mixin)."""


class _Cycle(Exception):
    pass


class GraphWalk:
    """Where a socket's value comes from. Needs the compiler's `problem`."""

    def link_into(self, socket):
        """The valid, unmuted link into an input socket, or None."""
        tree = socket.id_data
        key = tree.as_pointer()
        links = self._links.get(key)
        if links is None:
            links = self._links[key] = {}
            for link in tree.links:
                links.setdefault(link.to_socket.as_pointer(), link)
        link = links.get(socket.as_pointer())
        if link is None or link.is_muted:
            return None
        if not link.is_valid:
            self.problem(f"invalid link from '{link.from_node.name}' to "
                         f"'{link.to_node.name}' ({socket.name}) ignored")
            return None
        return link

    def source(self, socket, ctx):
        """What feeds input `socket` in group context ctx (a tuple of group nodes), through
        reroutes, muted nodes, node groups and their Group Input/Output:
        None (unconnected), ("default", socket) (an unconnected socket whose value applies) or
        ("node", node, output socket, ctx)."""
        link = self.link_into(socket)
        if link is None:
            return None
        node, out = link.from_node, link.from_socket
        unlinked = None  # what the last link followed would give were it not there
        for _ in range(10000):  # a reroute loop cannot hang us
            if node.type == 'REROUTE':
                link = self.link_into(node.inputs[0])
                if link is None:
                    return None
                node, out = link.from_node, link.from_socket
                unlinked = None
            elif node.mute:
                inner = [l for l in node.internal_links if l.to_socket == out]
                if not inner:
                    return None
                src = inner[0].from_socket
                link = self.link_into(src)
                if link is None:
                    return ("default", src)
                node, out = link.from_node, link.from_socket
                unlinked = ("default", src)
            elif node.type == 'GROUP':
                tree = node.node_tree
                if tree is None:
                    self.problem(f"node group '{node.name}' has no node tree")
                    return None
                outputs = [n for n in tree.nodes if n.type == 'GROUP_OUTPUT']
                active = [n for n in outputs if n.is_active_output] or outputs
                if not active:
                    return None
                inner = next((s for s in active[0].inputs if s.identifier == out.identifier), None)
                if inner is None:
                    return None
                if len(ctx) > 32:
                    raise _Cycle(node.name)
                ctx = ctx + (node,)
                link = self.link_into(inner)
                if link is None:
                    return ("default", inner)
                node, out = link.from_node, link.from_socket
                unlinked = ("default", inner)
            elif node.type == 'GROUP_INPUT':
                if not ctx:
                    self.problem(f"Group Input '{node.name}' outside a node group")
                    return None
                group = ctx[-1]
                ctx = ctx[:-1]
                outer = next((s for s in group.inputs if s.identifier == out.identifier), None)
                if outer is None:
                    return None
                link = self.link_into(outer)
                if link is None:
                    return ("default", outer)
                node, out = link.from_node, link.from_socket
                unlinked = ("default", outer)
            elif node.type == 'SHADERTORGB':
                # EEVEE only: Cycles exports no node for it, so its links are dropped and what
                # they fed takes its own value (a shader input: no closure), and so here.
                self.problem(f"'{node.name}' (Shader to RGB) is EEVEE only: its link into "
                             f"{socket.name} is ignored, as in Cycles")
                return unlinked
            else:
                return ("node", node, out, ctx)
        raise _Cycle(node.name)

    @staticmethod
    def ctx_key(ctx):
        return tuple(n.as_pointer() for n in ctx)
