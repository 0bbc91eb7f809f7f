#!/usr/bin/env python3
"""Write small random-weight ONNX graphs shaped like the models users export.

    make_test_models.py OUT_DIR

For `humem models check` and its tests (tests/e2e/models_check.rs): each graph has the
inputs, outputs and dynamic axes of the export recipe it stands for (docs/using.md,
"The paper's models"), real layers (convolutions, pooling, fully connected, softmax,
normalisation) with seeded random weights, and costs a few milliseconds per image.
Only numpy and onnx are needed, as for tools/efficientnet_to_onnx.py.

  eigenplaces_like.onnx  EigenPlaces ResNet export: `image` [n, 3, 384, 512] (height and
                         width fixed, as torch.onnx.export with a dynamic batch only gives
                         them), ResNet-style stem and residual blocks, L2-normalised
                         features, GeM pooling, fully connected, L2 normalisation:
                         `descriptor` [n, 512].
  places365_like.onnx    Places365 ResNet-18 + Softmax export: `image` [n, 3, 224, 224],
                         `scene` [n, 365] class probabilities.
  yolo_seg_like.onnx     Ultralytics YOLO segment export with dynamic=True: `images`
                         [batch, 3, height, width]; `output0` [batch, 4 + 5 + 32, anchors]
                         (cx, cy, w, h in input pixels, 5 sigmoid class scores, 32 mask
                         coefficients; anchors of strides 8, 16 and 32) and `output1`
                         [batch, 32, mask_height, mask_width] prototypes at stride 4. As
                         in a real YOLO, upsampled coarse features are concatenated with
                         finer ones, so height and width must be multiples of 32.
  vit_like.onnx          A ViT-S/14-style descriptor (DINOv2-like): `pixel_values`
                         [n, 3, h, w], 14x14 patches cut by a Reshape that fails unless
                         h and w are multiples of 14, patch embedding Conv (kernel 14,
                         stride 14), a residual token MLP, mean over tokens, linear,
                         L2 normalisation: `embedding` [n, 384].

Every graph passes onnx.checker (full check, with shape inference).
"""
import os
import sys

import numpy as np
import onnx
from onnx import TensorProto, helper, numpy_helper

OPSET = 17
YOLO_CLASSES = 5  # as the docs' example: building, fence, street_light, billboard, traffic_sign
YOLO_MASKS = 32
VIT_PATCH, VIT_WIDTH, VIT_DIM = 14, 32, 384


class Graph:
    """Nodes and initialisers of one graph, with seeded random weights."""

    def __init__(self, seed):
        self.rng = np.random.default_rng(seed)
        self.nodes, self.inits, self.n = [], [], 0

    def const(self, array, dtype=np.float32):
        name = f'c{len(self.inits)}'
        self.inits.append(numpy_helper.from_array(np.asarray(array, dtype), name))
        return name

    def op(self, op_type, inputs, out=None, **attrs):
        self.n += 1
        out = out or f'{op_type.lower()}{self.n}'
        self.nodes.append(helper.make_node(op_type, inputs, [out], **attrs))
        return out

    def conv(self, x, cin, cout, k, stride=1, relu=True, pad=None):
        """Conv with He-initialised weights and a small bias; padding k // 2 unless given."""
        w = self.rng.normal(0, np.sqrt(2 / (cin * k * k)), (cout, cin, k, k))
        b = self.rng.normal(0, 0.01, cout)
        x = self.op('Conv', [x, self.const(w), self.const(b)], kernel_shape=[k, k],
                    strides=[stride, stride], pads=[k // 2 if pad is None else pad] * 4)
        return self.op('Relu', [x]) if relu else x

    def silu_conv(self, x, cin, cout, k, stride=1):
        x = self.conv(x, cin, cout, k, stride, relu=False)
        return self.op('Mul', [x, self.op('Sigmoid', [x])])

    def residual(self, x, c):
        """A ResNet basic block: conv, ReLU, conv, add, ReLU."""
        y = self.conv(self.conv(x, c, c, 3), c, c, 3, relu=False)
        return self.op('Relu', [self.op('Add', [x, y])])

    def linear(self, x, cin, cout):
        return self.op('Gemm', [x, self.const(self.rng.normal(0, np.sqrt(1 / cin), (cin, cout))),
                                self.const(self.rng.normal(0, 0.01, cout))])

    def stem(self, x):
        """ResNet stem: 7x7/2 conv, ReLU, 3x3/2 max pool (stride 4, 16 channels)."""
        x = self.conv(x, 3, 16, 7, 2)
        return self.op('MaxPool', [x], kernel_shape=[3, 3], strides=[2, 2], pads=[1, 1, 1, 1])

    def model(self, name, inputs, outputs, doc):
        graph = helper.make_graph(self.nodes, name, inputs, outputs, self.inits)
        model = helper.make_model(graph, opset_imports=[helper.make_opsetid('', OPSET)],
                                  producer_name='humem tools/make_test_models.py', ir_version=8)
        model.doc_string = doc
        onnx.checker.check_model(model, full_check=True)
        return model


def tensor(name, dims):
    return helper.make_tensor_value_info(name, TensorProto.FLOAT, dims)


def eigenplaces_like():
    g = Graph(1)
    x = g.stem('image')
    x = g.residual(x, 16)
    x = g.residual(g.conv(x, 16, 32, 3, 2), 32)
    x = g.residual(g.conv(x, 32, 64, 3, 2), 64)
    x = g.op('LpNormalization', [x], axis=1, p=2)  # EigenPlaces: L2Norm before GeM
    gem = g.op('Pow', [g.op('Clip', [x, g.const(1e-6)]), g.const(3.0)])
    gem = g.op('Flatten', [g.op('Pow', [g.op('GlobalAveragePool', [gem]), g.const(1 / 3)])])
    g.op('LpNormalization', [g.linear(gem, 64, 512)], out='descriptor', axis=1, p=2)
    return g.model('eigenplaces_like', [tensor('image', ['n', 3, 384, 512])],
                   [tensor('descriptor', ['n', 512])],
                   'EigenPlaces-shaped test graph (random weights): 512-d L2-normalised descriptor.')


def places365_like():
    g = Graph(2)
    x = g.residual(g.stem('image'), 16)
    x = g.residual(g.conv(x, 16, 32, 3, 2), 32)
    pooled = g.op('Flatten', [g.op('GlobalAveragePool', [x])])
    g.op('Softmax', [g.linear(pooled, 32, 365)], out='scene', axis=1)
    return g.model('places365_like', [tensor('image', ['n', 3, 224, 224])],
                   [tensor('scene', ['n', 365])],
                   'Places365-shaped test graph (random weights): softmax over 365 classes.')


def yolo_seg_like():
    g = Graph(3)
    channels = 4 + YOLO_CLASSES + YOLO_MASKS
    p2 = g.silu_conv(g.silu_conv('images', 3, 8, 3, 2), 8, 16, 3, 2)  # stride 4
    p3 = g.silu_conv(p2, 16, 16, 3, 2)  # stride 8
    p4 = g.silu_conv(p3, 16, 32, 3, 2)  # stride 16
    p5 = g.silu_conv(p4, 32, 32, 3, 2)  # stride 32
    # Top-down path: a coarse map doubled must match the finer one (multiples of 32).
    up = g.const([1, 1, 2, 2])
    empty = g.const([])
    p4 = g.op('Concat', [g.op('Resize', [p5, empty, up], mode='nearest'), p4], axis=1)  # 64
    p3 = g.op('Concat', [g.op('Resize', [p4, empty, up], mode='nearest'), p3], axis=1)  # 80
    flat = g.const([0, channels, -1], np.int64)
    levels = [g.op('Reshape', [g.conv(p, c, channels, 1, relu=False), flat])
              for p, c in ((p3, 80), (p4, 64), (p5, 32))]
    raw = g.op('Concat', levels, axis=2)  # [batch, channels, anchors]
    box, cls, coeffs = (g.op('Slice', [raw, g.const([a], np.int64), g.const([b], np.int64),
                                       g.const([1], np.int64)])
                        for a, b in ((0, 4), (4, 4 + YOLO_CLASSES), (4 + YOLO_CLASSES, channels)))
    # Boxes in input pixels: sigmoid times the input width.
    width = g.op('Cast', [g.op('Gather', [g.op('Shape', ['images']), g.const(3, np.int64)])],
                 to=TensorProto.FLOAT)
    box = g.op('Mul', [g.op('Sigmoid', [box]), width])
    g.op('Concat', [box, g.op('Sigmoid', [cls]), coeffs], out='output0', axis=1)
    g.op('Identity', [g.conv(p2, 16, YOLO_MASKS, 3, relu=False)], out='output1')
    return g.model('yolo_seg_like', [tensor('images', ['batch', 3, 'height', 'width'])],
                   [tensor('output0', ['batch', channels, 'anchors']),
                    tensor('output1', ['batch', YOLO_MASKS, 'mask_height', 'mask_width'])],
                   'YOLO-seg-shaped test graph (random weights), 5 classes, anchors layout.')


def vit_like():
    g = Graph(4)
    shape = g.op('Shape', ['pixel_values'])
    side = lambda axis: g.op('Div', [g.op('Gather', [shape, g.const([axis], np.int64)]),  # noqa: E731
                                     g.const([VIT_PATCH], np.int64)])
    patch = g.const([VIT_PATCH], np.int64)
    # [n, 3, h/14, 14, w/14, 14]: fails unless h and w are multiples of the patch.
    patches = g.op('Concat', [g.const([0, 3], np.int64), side(2), patch, side(3), patch], axis=0)
    x = g.op('Reshape', [g.op('Reshape', ['pixel_values', patches]), shape])
    x = g.conv(x, 3, VIT_WIDTH, VIT_PATCH, VIT_PATCH, relu=False, pad=0)  # patch embedding
    tokens = g.op('Transpose', [g.op('Reshape', [x, g.const([0, VIT_WIDTH, -1], np.int64)])],
                  perm=[0, 2, 1])  # [n, tokens, width]
    hidden = g.op('Relu', [g.op('MatMul', [tokens, g.const(
        g.rng.normal(0, np.sqrt(2 / VIT_WIDTH), (VIT_WIDTH, 2 * VIT_WIDTH)))])])
    mlp = g.op('MatMul', [hidden, g.const(g.rng.normal(0, np.sqrt(1 / VIT_WIDTH), (2 * VIT_WIDTH, VIT_WIDTH)))])
    pooled = g.op('ReduceMean', [g.op('Add', [tokens, mlp])], axes=[1], keepdims=0)
    g.op('LpNormalization', [g.linear(pooled, VIT_WIDTH, VIT_DIM)], out='embedding', axis=1, p=2)
    return g.model('vit_like', [tensor('pixel_values', ['n', 3, 'h', 'w'])],
                   [tensor('embedding', ['n', VIT_DIM])],
                   'ViT-S/14-shaped test graph (random weights): sides must be multiples of 14.')


MODELS = {
    'eigenplaces_like.onnx': eigenplaces_like,
    'places365_like.onnx': places365_like,
    'yolo_seg_like.onnx': yolo_seg_like,
    'vit_like.onnx': vit_like,
}


def main():
    if len(sys.argv) != 2:
        sys.exit(__doc__)
    out_dir = sys.argv[1]
    os.makedirs(out_dir, exist_ok=True)
    for name, build in MODELS.items():
        onnx.save(build(), os.path.join(out_dir, name))
    print(f'wrote {", ".join(MODELS)} to {out_dir}')


if __name__ == '__main__':
    main()
