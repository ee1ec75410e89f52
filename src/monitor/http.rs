//! `--http ADDR`: `/status` (JSON: every part's verdict, the flags, counters)
//! and `/metrics` (Prometheus text format) on a small HTTP server.

use std::net::SocketAddr;
use std::sync::{Arc, Mutex};

use axum::Router;
use axum::http::header;
use axum::routing::get;

use super::status::Status;
use crate::Failure;

/// Binds `addr` and serves the endpoints in the background. Fails (before
/// anything is read) if the address cannot be bound.
pub async fn serve(addr: SocketAddr, status: Arc<Mutex<Status>>) -> Result<(), Failure> {
    let listener = tokio::net::TcpListener::bind(addr)
        .await
        .map_err(|e| Failure::BadInput(format!("--http {addr}: cannot listen: {e}")))?;
    let for_status = status.clone();
    let app = Router::new()
        .route(
            "/status",
            get(move || {
                let body = for_status.lock().map(|s| s.json()).unwrap_or_default();
                async move { ([(header::CONTENT_TYPE, "application/json")], body) }
            }),
        )
        .route(
            "/metrics",
            get(move || {
                let body = status.lock().map(|s| s.metrics()).unwrap_or_default();
                async move { ([(header::CONTENT_TYPE, "text/plain; version=0.0.4")], body) }
            }),
        );
    tokio::spawn(async move {
        if let Err(e) = axum::serve(listener, app).await {
            eprintln!("warning: --http: {e}");
        }
    });
    Ok(())
}
