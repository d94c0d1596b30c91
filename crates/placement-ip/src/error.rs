/// Errors of placement: bad instances, infeasible limits, solver failures.
#[derive(Debug, thiserror::Error)]
pub enum PlacementError {
    #[error("invalid placement input: {0}")]
    Invalid(String),
    #[error("infeasible: {0}")]
    Infeasible(String),
    #[error("solver: {0}")]
    Solver(String),
    #[error(transparent)]
    Sensor(#[from] hilo_sensor_models::SensorError),
    #[error(transparent)]
    Raycast(#[from] hilo_raycast::RaycastError),
}
