//! A dense matrix that travels with its dimensions.

use nalgebra::DMatrix;
use serde::{Deserialize, Serialize};

use crate::validate::check_finite;
use crate::ProtocolError;

/// Row-major dense matrix with explicit dimensions. `data.len() == rows * cols` is checked by
/// [`Matrix::check`] (decoding always calls it).
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[cfg_attr(feature = "schema", derive(schemars::JsonSchema))]
pub struct Matrix {
    pub rows: u32,
    pub cols: u32,
    pub data: Vec<f64>,
}

impl Matrix {
    pub fn zeros(rows: usize, cols: usize) -> Self {
        Matrix { rows: rows as u32, cols: cols as u32, data: vec![0.0; rows * cols] }
    }

    pub fn rows(&self) -> usize {
        self.rows as usize
    }

    pub fn cols(&self) -> usize {
        self.cols as usize
    }

    /// Entry `(i, j)`; `None` outside the matrix.
    pub fn get(&self, i: usize, j: usize) -> Option<f64> {
        (i < self.rows() && j < self.cols()).then(|| self.data[i * self.cols() + j])
    }

    /// Copy from an nalgebra matrix (which is column-major).
    pub fn from_dmatrix(m: &DMatrix<f64>) -> Self {
        let mut out = Matrix::zeros(m.nrows(), m.ncols());
        out.copy_from_dmatrix(m);
        out
    }

    /// Overwrite from an nalgebra matrix, reusing the allocation when the size is unchanged.
    pub fn copy_from_dmatrix(&mut self, m: &DMatrix<f64>) {
        self.rows = m.nrows() as u32;
        self.cols = m.ncols() as u32;
        self.data.resize(m.nrows() * m.ncols(), 0.0);
        let c = m.ncols();
        for i in 0..m.nrows() {
            for j in 0..c {
                self.data[i * c + j] = m[(i, j)];
            }
        }
    }

    /// To an nalgebra matrix. Call [`Matrix::check`] first (decoding does).
    pub fn to_dmatrix(&self) -> DMatrix<f64> {
        DMatrix::from_row_slice(self.rows(), self.cols(), &self.data)
    }

    /// Consistent dimensions, finite entries, and the expected shape where one is given.
    pub fn check(
        &self,
        field: &str,
        rows: Option<usize>,
        cols: Option<usize>,
    ) -> Result<(), ProtocolError> {
        let n = (self.rows as u64) * (self.cols as u64);
        if n != self.data.len() as u64 {
            return Err(ProtocolError::dim(
                format!("{field}.data"),
                format!("{}x{} = {n} entries", self.rows, self.cols),
                self.data.len(),
            ));
        }
        if let Some(r) = rows {
            if self.rows() != r {
                return Err(ProtocolError::dim(format!("{field}.rows"), r, self.rows));
            }
        }
        if let Some(c) = cols {
            if self.cols() != c {
                return Err(ProtocolError::dim(format!("{field}.cols"), c, self.cols));
            }
        }
        check_finite(field, &self.data)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn row_major_round_trip_through_nalgebra() {
        let m = DMatrix::from_fn(3, 4, |i, j| (10 * i + j) as f64);
        let p = Matrix::from_dmatrix(&m);
        assert_eq!(p.get(2, 1), Some(21.0));
        assert_eq!(p.data[4], 10.0);
        assert_eq!(p.to_dmatrix(), m);
        assert!(p.check("m", Some(3), Some(4)).is_ok());
        assert!(p.check("m", Some(4), None).is_err());
    }
}
