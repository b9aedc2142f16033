"""The partitioner for the compiled kernels' training graphs (imported on first compile: it
imports inductor, which takes a second)."""

import torch
from torch._functorch.partitioners import min_cut_rematerialization_partition
from torch._inductor.custom_graph_pass import CustomPartitionerFn, get_hash_for_files


class NoSavedMasks(CustomPartitionerFn):
    """The default partition of a training graph, unless it saves a boolean mask for the
    backward; then one that saves only the graph's inputs, the backward recomputing the forward's
    few dozen flops per row inside its own fused loop.

    The partitioner saves the cheapest intermediates to store, so a comparison mask (1 byte) before
    any float, but a bool buffer written from a vectorised CPU loop is converted lane by lane:
    about 9 ms per 1e6 rows, 9x the float stores it was meant to spare. Two or three such masks
    tripled the training forward of quat_to_euler, matrix_to_euler and matrix_to_quat. Kernels
    whose default partition saves only floats keep it (recomputing their trig would cost more).
    """

    def __call__(self, gm, joint_inputs, **kwargs):
        try:
            graph = torch.fx.Graph()  # a trial on a copy: the partitioner edits the graph it is given
            graph.output(graph.graph_copy(gm.graph, {}))
            fw, bw = min_cut_rematerialization_partition(torch.fx.GraphModule(gm, graph), joint_inputs, **kwargs)
            saves_mask = any(getattr(node.meta.get("val"), "dtype", None) == torch.bool
                             for node in bw.graph.find_nodes(op="placeholder"))
        except Exception:  # (private inductor APIs: on any surprise, the default partition)
            return min_cut_rematerialization_partition(gm, joint_inputs, **kwargs)
        if not saves_mask:
            return fw, bw
        with torch._functorch.config.patch(activation_memory_budget=0.0):
            return min_cut_rematerialization_partition(gm, joint_inputs, **kwargs)

    def uuid(self):
        return get_hash_for_files((__file__,))
