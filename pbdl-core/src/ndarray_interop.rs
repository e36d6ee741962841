//! Conversions between candle [`Tensor`]s and [`ndarray`] arrays (feature `ndarray`, on by
//! default).
//!
//! Rust numerics code holds its data in `ndarray`; pbdl's simulators and networks hold it in
//! candle tensors. These functions move data across without copying where the memory layout
//! allows it:
//!
//! | direction | function | copies? |
//! |---|---|---|
//! | owned array -> tensor | [`array_into_tensor`] | no, on the CPU, when the array is in standard (C) order; else one copy |
//! | borrowed array -> tensor | [`array_to_tensor`] | one copy (candle owns its buffers) |
//! | tensor -> borrowed view | [`with_array_view`] | no: the closure sees the tensor's own memory, strides included |
//! | tensor -> owned array | [`tensor_to_array`] | one copy (from any device) |
//!
//! Layouts agree: a tensor `[batch, channel, y, x]` becomes an array with the same axes, x
//! fastest. File readers that return `ndarray` arrays (NetCDF, Zarr) therefore plug into pbdl
//! through [`array_into_tensor`] with no glue.
//!
//! ```
//! use candle_core::{Device, Tensor};
//! use ndarray::{array, Axis};
//! use pbdl_core::ndarray_interop::{array_into_tensor, tensor_to_array, with_array_view};
//!
//! // A 2x3 field from ndarray into candle: the buffer moves, nothing is copied.
//! let field = array![[1.0f32, 2.0, 3.0], [4.0, 5.0, 6.0]];
//! let t = array_into_tensor(field, &Device::Cpu)?;
//! assert_eq!(t.dims(), &[2, 3]);
//!
//! // A transposed tensor is a strided view of the same memory; ndarray reads it in place.
//! let column_sums = with_array_view::<f32, _>(&t.t()?, |v| v.sum_axis(Axis(1)))?;
//! assert_eq!(column_sums.iter().copied().collect::<Vec<f32>>(), vec![5.0, 7.0, 9.0]);
//!
//! // And back to an owned array (a copy).
//! let back = tensor_to_array::<f32>(&(t * 2.0)?)?;
//! assert_eq!(back[[1, 2]], 12.0);
//! # Ok::<(), pbdl_core::Error>(())
//! ```

use crate::{Error, Result};
use candle_core::{Device, Storage, Tensor, WithDType};
use ndarray::{Array, ArrayBase, ArrayD, ArrayViewD, Data, Dimension, IxDyn, ShapeBuilder};

/// Moves an owned array into a tensor on `device`.
///
/// On the CPU an array in standard (row-major, C) order hands its buffer to candle without a
/// copy; any other layout (Fortran order, a transposed or sliced array) is copied once into
/// standard order first.
pub fn array_into_tensor<T: WithDType, D: Dimension>(array: Array<T, D>, device: &Device) -> Result<Tensor> {
    let shape = array.shape().to_vec();
    let data = if array.is_standard_layout() {
        match array.into_raw_vec_and_offset() {
            // A standard-layout array whose data starts at the buffer's start owns exactly its
            // elements, in order.
            (vec, Some(0) | None) => vec,
            (vec, Some(offset)) => vec[offset..].to_vec(),
        }
    } else {
        array.iter().copied().collect()
    };
    Ok(Tensor::from_vec(data, shape, device)?)
}

/// Copies any array or view (any layout) into a new tensor on `device`.
pub fn array_to_tensor<T: WithDType, S: Data<Elem = T>, D: Dimension>(
    array: &ArrayBase<S, D>,
    device: &Device,
) -> Result<Tensor> {
    let shape = array.shape().to_vec();
    let data: Vec<T> = match array.as_slice() {
        Some(slice) => slice.to_vec(),
        None => array.iter().copied().collect(),
    };
    Ok(Tensor::from_vec(data, shape, device)?)
}

/// Copies a tensor (any device, any layout) into an owned array of the same shape.
///
/// The tensor's dtype must be `T`; convert first with `.to_dtype(..)` otherwise.
pub fn tensor_to_array<T: WithDType>(tensor: &Tensor) -> Result<ArrayD<T>> {
    check_dtype::<T>(tensor)?;
    let data: Vec<T> = tensor.flatten_all()?.to_vec1()?;
    Array::from_shape_vec(IxDyn(tensor.dims()), data).map_err(|e| invalid(format!("{e}")))
}

/// Runs `f` on a read-only `ndarray` view of a CPU tensor's memory, without copying.
///
/// The view has the tensor's shape and strides, so a transposed, narrowed or broadcast tensor
/// is seen as it is. The view cannot outlive the call because candle guards its storage with
/// a lock while it is borrowed. The tensor must live on the CPU and have dtype `T`; for other
/// devices use [`tensor_to_array`].
pub fn with_array_view<T: WithDType, R>(tensor: &Tensor, f: impl FnOnce(ArrayViewD<'_, T>) -> R) -> Result<R> {
    check_dtype::<T>(tensor)?;
    let (storage, layout) = tensor.storage_and_layout();
    let cpu = match &*storage {
        Storage::Cpu(cpu) => cpu,
        _ => {
            return Err(invalid(format!(
                "the tensor lives on {:?}; move it with `.to_device(&Device::Cpu)` or use `tensor_to_array`",
                tensor.device()
            )))
        }
    };
    let data: &[T] = cpu.as_slice::<T>()?;
    let data = &data[layout.start_offset()..];
    let view = ArrayViewD::from_shape(IxDyn(layout.dims()).strides(IxDyn(layout.stride())), data).map_err(|e| {
        invalid(format!("layout {:?} / strides {:?} cannot be viewed: {e}", layout.dims(), layout.stride()))
    })?;
    Ok(f(view))
}

fn check_dtype<T: WithDType>(tensor: &Tensor) -> Result<()> {
    if tensor.dtype() != T::DTYPE {
        return Err(invalid(format!(
            "the tensor has dtype {:?} but the array element is {:?}; convert with `.to_dtype(DType::{:?})` first",
            tensor.dtype(),
            T::DTYPE,
            T::DTYPE
        )));
    }
    Ok(())
}

fn invalid(reason: String) -> Error {
    Error::InvalidArgument { op: "ndarray_interop", arg: "tensor", reason }
}

#[cfg(test)]
mod tests {
    use super::*;
    use candle_core::DType;
    use ndarray::{s, Array3, ShapeBuilder};

    fn ramp(shape: &[usize]) -> Tensor {
        let n: usize = shape.iter().product();
        Tensor::arange(0f32, n as f32, &Device::Cpu).unwrap().reshape(shape).unwrap()
    }

    #[test]
    fn standard_layout_array_moves_without_copy() {
        let a = Array3::from_shape_fn((2, 3, 4), |(i, j, k)| (i * 100 + j * 10 + k) as f64);
        let ptr = a.as_ptr();
        let t = array_into_tensor(a, &Device::Cpu).unwrap();
        assert_eq!(t.dims(), &[2, 3, 4]);
        assert_eq!(t.get(1).unwrap().get(2).unwrap().get(3).unwrap().to_scalar::<f64>().unwrap(), 123.0);
        // The tensor's storage is the array's former buffer.
        let (storage, _) = t.storage_and_layout();
        let Storage::Cpu(cpu) = &*storage else { panic!("cpu") };
        assert_eq!(cpu.as_slice::<f64>().unwrap().as_ptr(), ptr);
    }

    #[test]
    fn fortran_order_and_sliced_arrays_are_copied_in_logical_order() {
        let f = Array::from_shape_vec((2, 3).f(), vec![1f32, 4.0, 2.0, 5.0, 3.0, 6.0]).unwrap();
        let t = array_into_tensor(f.clone(), &Device::Cpu).unwrap();
        assert_eq!(t.to_vec2::<f32>().unwrap(), vec![vec![1.0, 2.0, 3.0], vec![4.0, 5.0, 6.0]]);
        let sliced = Array3::from_shape_fn((3, 4, 5), |(i, j, k)| (i * 100 + j * 10 + k) as f32);
        let part = sliced.slice(s![1.., ..;2, 3]).to_owned();
        let t = array_into_tensor(sliced.slice_move(s![1.., ..;2, 3]), &Device::Cpu).unwrap();
        assert_eq!(tensor_to_array::<f32>(&t).unwrap().into_dimensionality().unwrap(), part);
        let t2 = array_to_tensor(&f.t(), &Device::Cpu).unwrap();
        assert_eq!(t2.to_vec2::<f32>().unwrap(), vec![vec![1.0, 4.0], vec![2.0, 5.0], vec![3.0, 6.0]]);
    }

    #[test]
    fn views_follow_narrow_transpose_and_broadcast() {
        let t = ramp(&[2, 3, 4]);
        let narrowed = t.narrow(2, 1, 2).unwrap().transpose(0, 1).unwrap();
        let expect = tensor_to_array::<f32>(&narrowed).unwrap();
        with_array_view::<f32, _>(&narrowed, |v| assert_eq!(v, expect.view())).unwrap();
        let row = ramp(&[1, 4]).broadcast_as((3, 4)).unwrap();
        let sum = with_array_view::<f32, _>(&row, |v| v.sum()).unwrap();
        assert_eq!(sum, 3.0 * 6.0);
    }

    #[test]
    fn wrong_dtype_is_a_typed_error_that_says_what_to_do() {
        let t = ramp(&[2, 2]).to_dtype(DType::F64).unwrap();
        let e = tensor_to_array::<f32>(&t).unwrap_err().to_string();
        assert!(e.contains("to_dtype"), "{e}");
        let e = with_array_view::<f32, _>(&t, |_| ()).unwrap_err().to_string();
        assert!(e.contains("F64"), "{e}");
    }
}
