//! A model's signature: the inputs and outputs its graph declares.
//!
//! Read once from a loaded session ([`Io::of`]) and then plain data, so
//! that the graph checks ([`crate::check::graph`]), the errors that name a
//! tensor ([`crate::error`]) and the loaders ([`crate::objects`], the
//! crate root) share it without depending on each other. A leaf: it uses
//! nothing of the crate.

use std::fmt;

use ort::session::Session;
use ort::value::{Outlet, ValueType};

/// Whether a tensor is an input or an output.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Kind {
    /// A graph input.
    Input,
    /// A graph output.
    Output,
}

impl fmt::Display for Kind {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        f.write_str(match self {
            Kind::Input => "input",
            Kind::Output => "output",
        })
    }
}

/// One axis of a declared shape.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Dim {
    /// A fixed length.
    Fixed(usize),
    /// Any length, with the graph's symbol for it (may be empty).
    Dynamic(String),
}

impl Dim {
    pub(crate) fn fixed(&self) -> Option<usize> {
        match self {
            Dim::Fixed(n) => Some(*n),
            Dim::Dynamic(_) => None,
        }
    }
}

impl fmt::Display for Dim {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Dim::Fixed(n) => write!(f, "{n}"),
            Dim::Dynamic(s) if s.is_empty() => f.write_str("?"),
            Dim::Dynamic(s) => f.write_str(s),
        }
    }
}

/// A tensor as the graph declares it.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Tensor {
    /// Its name.
    pub name: String,
    /// Element type as ONNX Runtime names it (`f32`, `f16`, `i64`, …).
    pub element: String,
    /// Its axes; `None` where the graph declares no shape.
    pub dims: Option<Vec<Dim>>,
}

impl Tensor {
    fn of(outlet: &Outlet) -> Tensor {
        let (element, dims) = match outlet.dtype() {
            ValueType::Tensor {
                ty,
                shape,
                dimension_symbols,
            } => {
                let dims = shape
                    .iter()
                    .enumerate()
                    .map(|(i, &d)| match usize::try_from(d) {
                        Ok(n) => Dim::Fixed(n),
                        Err(_) => {
                            Dim::Dynamic(dimension_symbols.get(i).cloned().unwrap_or_default())
                        }
                    })
                    .collect::<Vec<_>>();
                // ONNX Runtime reports an undeclared shape as rank 0.
                (ty.to_string(), (!dims.is_empty()).then_some(dims))
            }
            other => (other.to_string(), None),
        };
        Tensor {
            name: outlet.name().to_string(),
            element,
            dims,
        }
    }

    /// The shape as written in messages: `[n, 3, 384, 512]`, `[?]` undeclared.
    pub fn shape(&self) -> String {
        match &self.dims {
            None => "[shape not declared]".into(),
            Some(dims) => {
                let dims: Vec<String> = dims.iter().map(Dim::to_string).collect();
                format!("[{}]", dims.join(", "))
            }
        }
    }
}

impl fmt::Display for Tensor {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{} {} {}", self.name, self.element, self.shape())
    }
}

/// A graph's declared inputs and outputs.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Io {
    /// Its inputs, in order.
    pub inputs: Vec<Tensor>,
    /// Its outputs, in order.
    pub outputs: Vec<Tensor>,
}

impl Io {
    /// What `session`'s graph declares.
    pub fn of(session: &Session) -> Io {
        Io {
            inputs: session.inputs().iter().map(Tensor::of).collect(),
            outputs: session.outputs().iter().map(Tensor::of).collect(),
        }
    }

    pub(crate) fn list(tensors: &[Tensor]) -> String {
        if tensors.is_empty() {
            return "none".into();
        }
        let all: Vec<String> = tensors.iter().map(Tensor::to_string).collect();
        all.join(", ")
    }
}
