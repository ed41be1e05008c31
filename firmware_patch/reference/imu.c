/* Reference firmware: the LSM6DSL (acc +-4 g, gyro +-2000 dps) on SPI2, in the board's axes.
 *
 * Sensor_IO_Read/Sensor_IO_Write have the name and arguments of ST's sensor I/O functions, and the handle's byte 3
 * is the SPI device number as in ST's DrvContextTypeDef: the emulated board replaces exactly these two functions
 * with its sensor models, so the SPI code inside them only runs on the drone. */
#include "ref.h"
#include "regs.h"

typedef struct {
  uint8_t who_am_i;
  uint8_t if_type;    /* 1: SPI */
  uint8_t address;
  uint8_t spi_device; /* 0 LSM6DSL, 1 LIS2MDL, 2 LPS22HB */
} sensor_handle_t;

static sensor_handle_t lsm6dsl = {0x6Au, 1u, 0u, 0u};

static void cs(uint8_t device, int active) {
  static const uint32_t port[3] = {GPIOA, GPIOB, GPIOC};
  static const uint8_t pin[3] = {8u, 12u, 13u};
  GPIO_BSRR(port[device]) = 1u << (pin[device] + (active ? 16u : 0u));
}

static void spi_send(uint8_t b) {
  while (!(SPI2_SR & 2u)) { /* TXE */
  }
  SPI2_DR = b;
  while (SPI2_SR & 0x80u) { /* BSY */
  }
}

uint8_t Sensor_IO_Write(void *handle, uint8_t reg, uint8_t *buf, uint16_t n) {
  sensor_handle_t *h = handle;
  cs(h->spi_device, 1);
  spi_send(reg & 0x7Fu);
  for (uint16_t i = 0; i < n; i++) spi_send(buf[i]);
  cs(h->spi_device, 0);
  return 0;
}

/* 3-wire read: send the address with bit 7 set, turn the data line around, clock the bytes in. */
uint8_t Sensor_IO_Read(void *handle, uint8_t reg, uint8_t *buf, uint16_t n) {
  sensor_handle_t *h = handle;
  cs(h->spi_device, 1);
  spi_send(reg | 0x80u);
  SPI2_CR1 &= ~(1u << 6);
  SPI2_CR1 &= ~(1u << 14); /* BIDIOE = 0: receive */
  SPI2_CR1 |= 1u << 6;
  for (uint16_t i = 0; i < n; i++) {
    while (!(SPI2_SR & 1u)) { /* RXNE */
    }
    buf[i] = (uint8_t)SPI2_DR;
  }
  SPI2_CR1 &= ~(1u << 6);
  SPI2_CR1 |= 1u << 14;
  SPI2_CR1 |= 1u << 6;
  cs(h->spi_device, 0);
  return 0;
}

/* WHO_AM_I check, then register auto-increment, acc 6.66 kHz +-4 g, gyro 416 Hz +-2000 dps. 0 = ok. */
int imu_init(void) {
  uint8_t v = 0;
  Sensor_IO_Read(&lsm6dsl, 0x0Fu, &v, 1u);
  if (v != lsm6dsl.who_am_i) return -1;
  v = 0x44u; /* CTRL3_C: BDU, IF_INC */
  Sensor_IO_Write(&lsm6dsl, 0x12u, &v, 1u);
  v = 0xA8u; /* CTRL1_XL */
  Sensor_IO_Write(&lsm6dsl, 0x10u, &v, 1u);
  v = 0x6Cu; /* CTRL2_G */
  Sensor_IO_Write(&lsm6dsl, 0x11u, &v, 1u);
  return 0;
}

/* One sample as integer mg and mdps in the board's axes (x right, y forward, z up): the sensor's x is the
 * board's y, the sensor's y the board's -x. Scaling as the driver does: (int32_t)(raw * sensitivity). */
void imu_read(int32_t acc_mg[3], int32_t gyro_mdps[3]) {
  uint8_t r[12]; /* OUTX_L_G .. OUTZ_H_XL */
  int32_t g[3], a[3];
  Sensor_IO_Read(&lsm6dsl, 0x22u, r, 12u);
  for (int i = 0; i < 3; i++) {
    g[i] = (int32_t)((float)(int16_t)(r[2 * i] | (r[2 * i + 1] << 8)) * 70.0f);
    a[i] = (int32_t)((float)(int16_t)(r[6 + 2 * i] | (r[6 + 2 * i + 1] << 8)) * 0.122f);
  }
  acc_mg[0] = -a[1];
  acc_mg[1] = a[0];
  acc_mg[2] = a[2];
  gyro_mdps[0] = -g[1];
  gyro_mdps[1] = g[0];
  gyro_mdps[2] = g[2];
}
