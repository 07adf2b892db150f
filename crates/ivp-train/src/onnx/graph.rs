//! The network of a vector variant as one ONNX graph (MODEL.md, "ONNX"): inputs `prior`, `depth`
//! and `hole`, output `vectors`, every size dynamic, standard operators of opset 17 only.
//!
//! The graph follows `IvpNet::masked_output` layer by layer (ivp-core's `nn/model.rs`): the same
//! convolutions with their strides and paddings, the depth head's bilinear upsampling with
//! half-pixel centres (`Resize`, `linear`, `half_pixel`: PyTorch's `align_corners=False`), and the
//! decoder's nearest x2 upsampling cropped to the skip connection's size (`Resize` by scales
//! (1, 1, 2, 2), `nearest`, `asymmetric`, `floor`, then `Slice` to the skip's height and width).
//! The crop is why any height and width work without padding: a stride-2 level of a side `s` has
//! `ceil(s / 2)` pixels, which upsample to `s` or `s + 1`.

use candle_core::Tensor;
use ivp_core::nn::model::{Conv, IvpNet, Variant};

use super::proto::{
    attribute_type, AttributeProto, Dimension, GraphProto, ModelProto, NodeProto, OperatorSetIdProto,
    StringStringEntryProto, TensorProto, TensorShapeProto, TensorTypeProto, TypeProto, ValueInfoProto, FLOAT, INT64,
};

/// The operator set the graph is written for (`Shape` with `start` and `end` needs 15).
pub const OPSET: i64 = 17;

/// The IR version of opset 17 (ONNX 1.12).
pub const IR_VERSION: i64 = 8;

#[derive(Debug, thiserror::Error)]
pub enum GraphError {
    #[error(
        "the `{0}` variant predicts colours, not vectors: ONNX export covers the vector variants \
         (full, no-tg, no-depth)"
    )]
    NotVectors(Variant),
    #[error("parameter of `{layer}`: {source}")]
    Parameter { layer: String, source: candle_core::Error },
}

/// The ONNX model of `net`, with `metadata` as its `metadata_props`.
pub fn onnx_model(net: &IvpNet, metadata: &[(String, String)]) -> Result<ModelProto, GraphError> {
    let variant = net.config().variant;
    if !variant.predicts_vectors() {
        return Err(GraphError::NotVectors(variant));
    }
    let mut g = GraphBuilder::default();
    let depth = match net.depth_head() {
        Some(head) => {
            let [c1, c2, c3, c4] = head.layers();
            let x = g.conv("depth.c1", "depth", c1, true)?;
            let x = g.conv("depth.c2", &x, c2, true)?;
            let x = g.resize_bilinear_2x("depth.up3", &x);
            let x = g.conv("depth.c3", &x, c3, true)?;
            let x = g.resize_bilinear_to("depth.up4", &x, "depth");
            let x = g.conv("depth.c4", &x, c4, false)?;
            g.node("Sigmoid", "depth.normalised", &[&x], vec![])
        }
        None => g.zeros_like("depth.zeros", "depth"),
    };
    let prior = match variant {
        Variant::NoTemporalPrior => g.zeros_like("prior.zeros", "prior"),
        _ => "prior".to_string(),
    };
    let x = g.node("Concat", "unet.input", &[&prior, &depth], vec![int("axis", 1)]);
    let [e1, e2, e3, e4, e5] = net.encoder();
    let x1 = g.conv("e1", &x, e1, true)?;
    let x2 = g.conv("e2", &x1, e2, true)?;
    let x3 = g.conv("e3", &x2, e3, true)?;
    let x4 = g.conv("e4", &x3, e4, true)?;
    let x5 = g.conv("e5", &x4, e5, true)?;
    let [d6, d7, d8, d9] = net.decoder();
    let y = g.upsample_concat("up6", &x5, &x4);
    let y = g.conv("d6", &y, d6, true)?;
    let y = g.upsample_concat("up7", &y, &x3);
    let y = g.conv("d7", &y, d7, true)?;
    let y = g.upsample_concat("up8", &y, &x2);
    let y = g.conv("d8", &y, d8, true)?;
    let y = g.upsample_concat("up9", &y, &x1);
    let y = g.conv("d9", &y, d9, false)?;
    g.node("Mul", "vectors", &[&y, "hole"], vec![]);

    let graph = GraphProto {
        node: g.nodes,
        name: format!("ivp-{variant}"),
        initializer: g.initializers,
        doc_string: "ivp's infilling-vector network: see MODEL.md".into(),
        input: vec![
            tensor_info("prior", 2, "temporal prior in pixels (x, y); zeros without frame n-2"),
            tensor_info("depth", 1, "warped depth d^w_{n+1} in scene units, 0 in every hole"),
            tensor_info("hole", 1, "1 on the disocclusions to predict, else 0"),
        ],
        output: vec![tensor_info("vectors", 2, "infilling vectors in pixels (x, y), 0 outside `hole`")],
    };
    Ok(ModelProto {
        ir_version: IR_VERSION,
        producer_name: "ivp".into(),
        producer_version: env!("CARGO_PKG_VERSION").into(),
        doc_string: String::new(),
        graph: Some(graph),
        opset_import: vec![OperatorSetIdProto { domain: String::new(), version: OPSET }],
        metadata_props: metadata
            .iter()
            .map(|(key, value)| StringStringEntryProto { key: key.clone(), value: value.clone() })
            .collect(),
    })
}

/// Nodes and initialisers in the order they are added; every value is named after what it is.
#[derive(Default)]
struct GraphBuilder {
    nodes: Vec<NodeProto>,
    initializers: Vec<TensorProto>,
}

impl GraphBuilder {
    /// Adds a node of `op` whose one output is `output`; returns `output`.
    fn node(&mut self, op: &str, output: &str, inputs: &[&str], attribute: Vec<AttributeProto>) -> String {
        self.nodes.push(NodeProto {
            input: inputs.iter().map(|s| s.to_string()).collect(),
            output: vec![output.to_string()],
            name: output.to_string(),
            op_type: op.to_string(),
            attribute,
        });
        output.to_string()
    }

    fn f32_initializer(&mut self, name: &str, t: &Tensor) -> candle_core::Result<String> {
        let values = t.flatten_all()?.to_vec1::<f32>()?;
        self.initializers.push(TensorProto {
            dims: t.dims().iter().map(|&d| d as i64).collect(),
            data_type: FLOAT,
            name: name.to_string(),
            raw_data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
        });
        Ok(name.to_string())
    }

    fn i64_initializer(&mut self, name: &str, values: &[i64]) -> String {
        if !self.initializers.iter().any(|t| t.name == name) {
            self.initializers.push(TensorProto {
                dims: vec![values.len() as i64],
                data_type: INT64,
                name: name.to_string(),
                raw_data: values.iter().flat_map(|v| v.to_le_bytes()).collect(),
            });
        }
        name.to_string()
    }

    /// `layer`'s convolution of `x` (weights named as in the model file), then ReLU if `relu`.
    fn conv(&mut self, layer: &str, x: &str, conv: &Conv, relu: bool) -> Result<String, GraphError> {
        let parameter = |source| GraphError::Parameter { layer: layer.to_string(), source };
        let weight = self.f32_initializer(&format!("{layer}.weight"), conv.weight()).map_err(parameter)?;
        let bias = self.f32_initializer(&format!("{layer}.bias"), conv.bias()).map_err(parameter)?;
        let kernel = conv.weight().dims()[3] as i64;
        let (stride, pad) = (conv.stride() as i64, conv.padding() as i64);
        let attributes =
            vec![ints("kernel_shape", &[kernel, kernel]), ints("strides", &[stride, stride]), ints("pads", &[pad; 4])];
        let output = if relu { format!("{layer}.conv") } else { layer.to_string() };
        self.node("Conv", &output, &[x, &weight, &bias], attributes);
        Ok(if relu { self.node("Relu", layer, &[&output], vec![]) } else { output })
    }

    /// `x` upsampled bilinearly by 2 with half-pixel centres.
    fn resize_bilinear_2x(&mut self, name: &str, x: &str) -> String {
        let scales = self.f32_scales_2x();
        self.node("Resize", name, &[x, "", &scales], bilinear())
    }

    /// `x` resized bilinearly (half-pixel centres) to the height and width of `like`.
    fn resize_bilinear_to(&mut self, name: &str, x: &str, like: &str) -> String {
        let batch_channels = self.node("Shape", &format!("{name}.batch_channels"), &[x], vec![int("end", 2)]);
        let height_width = self.node("Shape", &format!("{name}.height_width"), &[like], vec![int("start", 2)]);
        let sizes =
            self.node("Concat", &format!("{name}.sizes"), &[&batch_channels, &height_width], vec![int("axis", 0)]);
        self.node("Resize", name, &[x, "", "", &sizes], bilinear())
    }

    /// `x` upsampled by 2 (nearest), cropped to the size of `skip`, and `skip` after it in channels.
    fn upsample_concat(&mut self, name: &str, x: &str, skip: &str) -> String {
        let scales = self.f32_scales_2x();
        let nearest = vec![
            string("mode", "nearest"),
            string("coordinate_transformation_mode", "asymmetric"),
            string("nearest_mode", "floor"),
        ];
        let up = self.node("Resize", &format!("{name}.nearest"), &[x, "", &scales], nearest);
        let height_width = self.node("Shape", &format!("{name}.skip_size"), &[skip], vec![int("start", 2)]);
        let starts = self.i64_initializer("const.zeros2", &[0, 0]);
        let axes = self.i64_initializer("const.axes_hw", &[2, 3]);
        let cropped = self.node("Slice", &format!("{name}.cropped"), &[&up, &starts, &height_width, &axes], vec![]);
        self.node("Concat", name, &[&cropped, skip], vec![int("axis", 1)])
    }

    /// Zeros of the shape of `like`.
    fn zeros_like(&mut self, name: &str, like: &str) -> String {
        let shape = self.node("Shape", &format!("{name}.shape"), &[like], vec![]);
        let zero =
            TensorProto { dims: vec![1], data_type: FLOAT, name: String::new(), raw_data: 0f32.to_le_bytes().into() };
        let value = AttributeProto {
            name: "value".into(),
            t: Some(zero),
            r#type: attribute_type::TENSOR,
            ..Default::default()
        };
        self.node("ConstantOfShape", name, &[&shape], vec![value])
    }

    fn f32_scales_2x(&mut self) -> String {
        const NAME: &str = "const.scales_2x";
        if !self.initializers.iter().any(|t| t.name == NAME) {
            self.initializers.push(TensorProto {
                dims: vec![4],
                data_type: FLOAT,
                name: NAME.into(),
                raw_data: [1f32, 1.0, 2.0, 2.0].iter().flat_map(|v| v.to_le_bytes()).collect(),
            });
        }
        NAME.into()
    }
}

/// `Resize`'s attributes for PyTorch's `bilinear, align_corners=False`.
fn bilinear() -> Vec<AttributeProto> {
    vec![string("mode", "linear"), string("coordinate_transformation_mode", "half_pixel")]
}

/// A graph input or output: f32 (batch, `channels`, height, width), batch and sizes symbolic.
fn tensor_info(name: &str, channels: i64, doc: &str) -> ValueInfoProto {
    let symbol = |s: &str| Dimension { dim_value: None, dim_param: Some(s.into()) };
    let dims = vec![
        symbol("batch"),
        Dimension { dim_value: Some(channels), dim_param: None },
        symbol("height"),
        symbol("width"),
    ];
    ValueInfoProto {
        name: name.into(),
        r#type: Some(TypeProto {
            tensor_type: Some(TensorTypeProto { elem_type: FLOAT, shape: Some(TensorShapeProto { dim: dims }) }),
        }),
        doc_string: doc.into(),
    }
}

fn int(name: &str, i: i64) -> AttributeProto {
    AttributeProto { name: name.into(), i, r#type: attribute_type::INT, ..Default::default() }
}

fn ints(name: &str, values: &[i64]) -> AttributeProto {
    AttributeProto { name: name.into(), ints: values.to_vec(), r#type: attribute_type::INTS, ..Default::default() }
}

fn string(name: &str, s: &str) -> AttributeProto {
    AttributeProto { name: name.into(), s: s.as_bytes().to_vec(), r#type: attribute_type::STRING, ..Default::default() }
}
