//! Types by shape: what two modules' type ids mean, so that a value of the shader's can be
//! handed to a function of the library's (and bitcast where only the signedness differs).

use rspirv::dr::{Instruction, Operand};
use rspirv::spirv::{Op, StorageClass, Word};
use std::collections::HashMap;

/// The type declarations of one or more modules whose ids do not overlap.
#[derive(Default)]
pub(crate) struct Types {
    decls: HashMap<Word, Instruction>,
}

/// A type's shape, as far as the pass compares them.
#[derive(Clone, Debug, PartialEq, Eq, Hash)]
pub(crate) enum Shape {
    Void,
    Bool,
    Int {
        width: u32,
        signed: bool,
    },
    Float {
        width: u32,
    },
    Vector(Box<Shape>, u32),
    Matrix(Box<Shape>, u32),
    Pointer(StorageClass, Box<Shape>),
    /// An array of a constant length.
    Array(Box<Shape>, u32),
    /// Anything else, by id (structs, arrays, images, ...).
    Other(Word),
}

impl Types {
    pub fn add_all<'a>(&mut self, insts: impl IntoIterator<Item = &'a Instruction>) {
        for inst in insts {
            if let Some(id) = inst.result_id {
                self.decls.insert(id, inst.clone());
            }
        }
    }

    pub fn insert(&mut self, inst: &Instruction) {
        if let Some(id) = inst.result_id {
            self.decls.insert(id, inst.clone());
        }
    }

    pub fn get(&self, id: Word) -> Option<&Instruction> {
        self.decls.get(&id)
    }

    /// A pointer type's storage class and pointee.
    pub fn pointer(&self, id: Word) -> Option<(StorageClass, Word)> {
        let inst = self.get(id)?;
        if inst.class.opcode != Op::TypePointer {
            return None;
        }
        match (inst.operands.first(), inst.operands.get(1)) {
            (Some(Operand::StorageClass(sc)), Some(Operand::IdRef(p))) => Some((*sc, *p)),
            _ => None,
        }
    }

    /// An array's (or runtime array's) element type.
    pub fn element(&self, id: Word) -> Option<Word> {
        let inst = self.get(id)?;
        match inst.class.opcode {
            Op::TypeArray | Op::TypeRuntimeArray => match inst.operands.first() {
                Some(Operand::IdRef(e)) => Some(*e),
                _ => None,
            },
            _ => None,
        }
    }

    /// The value of a 32-bit integer constant.
    pub fn constant_u32(&self, id: Word) -> Option<u32> {
        let inst = self.get(id)?;
        match (inst.class.opcode, inst.operands.first()) {
            (Op::Constant, Some(Operand::LiteralBit32(v))) => Some(*v),
            _ => None,
        }
    }

    pub fn shape(&self, id: Word) -> Shape {
        self.shape_within(id, 0)
    }

    fn shape_within(&self, id: Word, depth: u32) -> Shape {
        let Some(inst) = self
            .get(id)
            .filter(|_| depth <= super::queries::MAX_NESTING)
        else {
            return Shape::Other(id);
        };
        let lit = |i: usize| match inst.operands.get(i) {
            Some(Operand::LiteralBit32(v)) => *v,
            _ => 0,
        };
        let idref = |i: usize| match inst.operands.get(i) {
            Some(Operand::IdRef(v)) => *v,
            _ => 0,
        };
        match inst.class.opcode {
            Op::TypeVoid => Shape::Void,
            Op::TypeBool => Shape::Bool,
            Op::TypeInt => Shape::Int {
                width: lit(0),
                signed: lit(1) != 0,
            },
            Op::TypeFloat => Shape::Float { width: lit(0) },
            Op::TypeVector => {
                Shape::Vector(Box::new(self.shape_within(idref(0), depth + 1)), lit(1))
            }
            Op::TypeMatrix => {
                Shape::Matrix(Box::new(self.shape_within(idref(0), depth + 1)), lit(1))
            }
            Op::TypeArray => match self.constant_u32(idref(1)) {
                Some(n) => Shape::Array(Box::new(self.shape_within(idref(0), depth + 1)), n),
                None => Shape::Other(id),
            },
            Op::TypePointer => match inst.operands.first() {
                Some(Operand::StorageClass(sc)) => {
                    Shape::Pointer(*sc, Box::new(self.shape_within(idref(1), depth + 1)))
                }
                _ => Shape::Other(id),
            },
            _ => Shape::Other(id),
        }
    }
}

impl Shape {
    /// Whether a value of this shape becomes one of `other` by `OpBitcast`: integers (or
    /// vectors of them) that differ only in signedness.
    pub fn bitcasts_to(&self, other: &Shape) -> bool {
        match (self, other) {
            (Shape::Int { width: a, .. }, Shape::Int { width: b, .. }) => a == b,
            (Shape::Vector(a, n), Shape::Vector(b, m)) => n == m && a.bitcasts_to(b),
            _ => false,
        }
    }
}
